"""``vdc-capture``: record runs of the arena as Rerun ``.rrd`` files."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

from capture.serial_link import LinkLost
from vdc.cli_inputs import campaign_inputs, output_options
from vdc.cli_support import (
    Command,
    command_line,
    command_of,
    progress_bar,
    run_command_line,
    say,
    settings_from_args,
    tasks_line,
)

if TYPE_CHECKING:
    from capture.run import CaptureOptions, RecordResult

PROG = "vdc-capture"


def _recording_options(args: argparse.Namespace) -> CaptureOptions:
    """The options every capture command's function takes from add_output_options' flags."""
    from capture.run import CaptureOptions

    return CaptureOptions(
        force=args.force, live_url=args.connect, spawn=args.spawn, progress=not args.quiet, log=say
    )


def _report_write_error(rec: RecordResult) -> None:
    """One line when the file could not take more, or the plug-in raised (its frames kept)."""
    if rec.write_error or rec.plugin_error:
        say(
            f"{PROG}: error: {rec.plugin_error or rec.write_error}; stopped at once: {rec.path} "
            f"is a readable recording of the first {rec.frames} frames."
        )


def _noun(noun: str, n: int) -> str:
    """``crash`` → ``crashes`` unless there is one."""
    return noun if n == 1 else noun + ("es" if noun.endswith(("s", "sh", "ch")) else "s")


def cmd_sim(args: argparse.Namespace) -> int:
    from capture.sim import SimSettings, record_sim

    res = record_sim(settings_from_args(SimSettings, args), args.out, _recording_options(args))
    _report_write_error(res)
    if res.complete:
        events = ", ".join(
            f"{n} {_noun(k.replace('_', ' '), n)}" for k, n in sorted(res.events.items())
        )
        print(
            f"wrote {res.path} ({res.frames} frames, {events or 'no events'}, "
            f"{res.size_mb:.0f} MB, {res.wall_time_s:.1f} s)"
        )
    elif not res.write_error:
        print(
            f"stopped by {res.stop_reason} after {res.frames} of {res.expected_frames} frames; "
            f"{res.path} is a valid recording of those frames ({res.size_mb:.0f} MB)"
        )
    return res.exit_status


def cmd_emulate_robot(args: argparse.Namespace) -> int:
    from capture.robot_emulator import EmulateSettings, emulate_robot, report_line

    link = args.link

    def announce(device: str) -> None:
        print(
            f"emulated Colias-IV on {device} (also {link}); waiting for the host's START",
            flush=True,
        )

    print(report_line(emulate_robot(settings_from_args(EmulateSettings, args), announce)))
    return 0


def cmd_robot(args: argparse.Namespace) -> int:
    from capture.robot_capture import RobotSettings, record_robot

    res = record_robot(settings_from_args(RobotSettings, args), args.out, _recording_options(args))
    rec = res.record
    _report_write_error(rec)
    if res.link_error:
        say(
            f"{PROG}: error: {res.link_error}; stopped: {rec.path} is a readable recording of "
            f"the {rec.frames} frames before it, with a link_error event."
        )
    print(
        f"wrote {rec.path}: {rec.frames} frames, link: "
        + ", ".join(f"{k} {v}" for k, v in res.link_stats.items())
        + f" ({rec.stop_reason})"
    )
    return rec.exit_status


def cmd_video(args: argparse.Namespace) -> int:
    from capture.video import VideoSettings, record_video

    s = settings_from_args(VideoSettings, args)
    # a calibration fit for this camera is shown by run_command_line (CalibrationNotes)
    res = record_video(s, args.out, _recording_options(args))
    rec = res.record
    _report_write_error(rec)
    if rec.write_error or rec.plugin_error:
        return rec.exit_status
    if res.lost:
        say(
            f"{PROG} video: note: frames lost inside the source ({res.lost} problem(s), "
            f"first: {res.first_loss}); each is a decode_error event in the recording, the "
            f"frames they cost counted once among the {res.dropped} dropped."
        )
    if res.decode_error:
        say(
            f"{PROG} video: note: decoding stopped after {rec.frames} frames "
            f"({res.decode_error}); the recording keeps every frame before it."
        )
    if rec.complete and res.info.get("kind") == "file" and res.container_frames is None:
        say(
            f"{PROG} video: note: the container states no frame count (nor a duration at a "
            "constant rate): frames lost after the last one read are unknown, not counted."
        )
    cal = res.calibration
    print(
        f"wrote {rec.path} ({rec.frames} frames, {res.repeats} repeated, {res.dropped} dropped; "
        f"calibration a={cal['a']:.5g}, b={cal['b']:.4g} ({cal['source']}, "
        f"{100 * cal['rms_rel_error']:.1f} % RMS); {rec.size_mb:.1f} MB, {rec.wall_time_s:.1f} s)"
    )
    return rec.exit_status


def cmd_campaign(args: argparse.Namespace) -> int:
    from capture.campaign import CampaignSettings, campaign
    from vdc.executors import Feedback

    settings = settings_from_args(CampaignSettings, args)
    # counted on the heartbeat line (terminals, VDC_PROGRESS=1); the campaign expects the runs
    # it records (not those already done)
    with progress_bar(None, "campaign", "run", args.quiet) as bar:
        res = campaign(settings, args.out, Feedback(say, bar.update, bar.expect))
    ran = len(res.outcomes) - len(res.failures)
    print(tasks_line(res, "runs", ran, "recorded"))
    if res.paths:
        print(f"runs table: {res.files.runs} ({res.runs.height} rows)")
    for key, error in res.failures:
        print(f"  FAILED {key}: {error}", file=sys.stderr)
    return 1 if res.failures else 0


# the sub-commands: each one's flags are its settings dataclass's fields (vdc.cli_support)
COMMANDS = {
    "sim": Command(
        "capture.sim:SimSettings",
        cmd_sim,
        "simulate the arena and a Colias-IV robot (no hardware needed)",
        "Simulate the paper's arena (1.4 x 0.8 m, LED walls 0.15 m high, white light ring) and "
        "a Colias-IV robot driving at 0.08 m/s and turning 80-100 deg at the ring. The robot's "
        "99x72 camera is rendered at 33 Hz, the online model runs on every frame, and "
        "everything is written to a Rerun recording with a default blueprint. The same seed "
        "gives the same frames and poses. Ctrl-C stops cleanly.",
        "examples:\n"
        "  vdc-capture sim --tf-hz 3 --minutes 30 --seed 1\n"
        "  vdc-capture sim --tf-schedule 0:30m,3:30m --out recordings/two-phase.rrd\n"
        "  vdc-capture sim --scene natural --tf-hz 3 --minutes 5 --spawn",
        inputs=output_options("recordings/<run id>.rrd"),
        models=True,
    ),
    "emulate-robot": Command(
        "capture.robot_emulator:EmulateSettings",
        cmd_emulate_robot,
        "a simulated Colias-IV on a pseudo-terminal, speaking the serial protocol",
        "Open a pseudo-terminal behind --link, print it, wait for the host's START and stream "
        "frames and on-board AVDM outputs from the simulator with the protocol of "
        "docs/guides/robot.md; fault injection for testing the link.",
    ),
    "robot": Command(
        "capture.robot_capture:RobotSettings",
        cmd_robot,
        "record a real Colias-IV: serial link + overhead tracker (same recording contract)",
        "Read frames and on-board model outputs from the robot's serial port and poses from "
        "an overhead camera with ArUco markers (ids 0-3 at the arena corners, 10 on the "
        "robot), join them on capture_time, and write the recording contract's entities. "
        "Ctrl-C or SIGTERM stops cleanly.",
        inputs=output_options("recordings/robot-<time>.rrd"),
    ),
    "video": Command(
        "capture.video:VideoSettings",
        cmd_video,
        "profile any video file, image sequence or camera (true timestamps)",
        "Decode SOURCE with its true presentation timestamps (variable frame rates and "
        "rotation metadata honoured), convert it to luma at the angular resolution the models "
        "were calibrated for, detect repeated and dropped frames, and run the AVDM on the new "
        "frames over true time. The decoding is calibrated for the source's frame rate and "
        "angular resolution on first use (cached per user). A camera index records until "
        "Ctrl-C.",
        "examples:\n"
        "  vdc-capture video clip.mp4 --fov-deg 66 --out recordings/clip.rrd\n"
        "  vdc-capture video 'frames/%05d.png' --fps 25 --fov-deg 90\n"
        "  vdc-capture video 0 --fov-deg 60 --spawn       # a webcam, live",
        inputs=output_options("recordings/video-<name>-<hash>.rrd"),
    ),
    "campaign": Command(
        "capture.campaign:CampaignSettings",
        cmd_campaign,
        "a grid of simulated runs (a campaign), on all cores or a Dask cluster",
        "Record one simulated run per point of a grid over `vdc-capture sim`'s settings. Each "
        "GRID item is FIELD=V1,V2,... (a sim flag name; integers also as A..B); items with one "
        "value apply to every run, the runs are the product of the rest. Every run is one "
        "task: it writes OUT/recordings/<key>.rrd, then its row OUT/runs/<key>.parquet. A "
        "re-run records only runs without a row (--force: all); a failed run is listed and "
        "does not stop the others (exit status 1). At the end the rows become "
        "OUT/runs.parquet.",
        "examples:\n"
        "  vdc-capture campaign behaviour=collision model=lgmd-plus-arena minutes=30 "
        "threshold=40,56,80 tf_hz=0,1,3 seed=1..5\n"
        "  vdc-capture campaign tf_hz=0,1,3 seed=1..3 minutes=5 --executor dask "
        "--scheduler tcp://head:8786\n"
        "  vdc-analyse batch results/campaign/recordings/*.rrd --model avdm --model "
        "avdm:beta=0.5",
        inputs=campaign_inputs,
        models=True,
    ),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser, with the flags of ``command`` generated (see ``vdc.cli_support``)."""
    return command_line(
        PROG,
        "Record runs of the arena as Rerun .rrd files (open them with `rerun FILE`).",
        COMMANDS,
        command,
    )


# old sub-command names -> their names now: they still run, and say so (one line on stderr)
ALIASES = {"sweep": "campaign"}  # `vdc-analyse sweep` is Fig. 3's, an unrelated command


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    old = next((a for a in argv if not a.startswith("-")), "")
    if old in ALIASES:
        print(f"{PROG} {old} is now {PROG} {ALIASES[old]} (an alias of it)", file=sys.stderr)
        argv[argv.index(old)] = ALIASES[old]
    # a lost link closes the recording cleanly with everything received: exit 1, not 2
    stopped = {LinkLost: "; the recording holds every frame received before"}
    return run_command_line(PROG, build_parser(command_of(argv, COMMANDS)), argv, stopped)
