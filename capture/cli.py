"""``vdc-capture``: record runs of the arena as Rerun ``.rrd`` files."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

from avdm.registry import describe_models
from capture.colias_link import LinkLost
from vdc.cli_support import (
    OneLineParser,
    UserError,
    add_executor_options,
    bind_commands,
    command_of,
    fail,
    positive_float,
    settings_from_args,
)

if TYPE_CHECKING:
    from capture.run import RecordResult

PROG = "vdc-capture"


def _non_negative_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


def _seed(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}")
    return v


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _recording_options(args: argparse.Namespace) -> dict:
    """The options every capture command's function takes from add_output_options' flags."""
    return {
        "force": args.force,
        "live_url": args.connect,
        "spawn": args.spawn,
        "progress": not args.quiet,
        "log": _stderr,
    }


def _report_write_error(rec: RecordResult) -> None:
    """One line when the file could not take more: what, where, and what it keeps."""
    if rec.write_error:
        _stderr(
            f"{PROG}: error: {rec.write_error}; stopped at once: {rec.path} is a readable "
            f"recording of the first {rec.frames} frames"
        )


def cmd_sim(args: argparse.Namespace) -> int:
    from capture.sim import SimSettings, record_sim

    res = record_sim(settings_from_args(SimSettings, args), args.out, **_recording_options(args))
    _report_write_error(res)
    if res.complete:
        events = ", ".join(f"{n} {k.replace('_', ' ')}s" for k, n in sorted(res.events.items()))
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
    from capture.colias_link import EmulateSettings, emulate_robot

    link = args.link

    def announce(device: str) -> None:
        print(
            f"emulated Colias-IV on {device} (also {link}); waiting for the host's START",
            flush=True,
        )

    report = emulate_robot(settings_from_args(EmulateSettings, args), announce)
    print(
        f"sent {len(report['intact'])} intact and {len(report['corrupted'])} corrupted "
        f"frames; dropped {len(report['dropped'])}; {len(report['lost_in_disconnect'])} "
        f"lost in {report['disconnects']} disconnect(s)"
    )
    return 0


def cmd_robot(args: argparse.Namespace) -> int:
    from capture.robot_capture import RobotSettings, record_robot

    res = record_robot(
        settings_from_args(RobotSettings, args), args.out, **_recording_options(args)
    )
    rec = res.record
    _report_write_error(rec)
    print(
        f"wrote {rec.path}: {rec.frames} frames, link: "
        + ", ".join(f"{k} {v}" for k, v in res.link_stats.items())
        + f" ({rec.stop_reason})"
    )
    return rec.exit_status


def cmd_video(args: argparse.Namespace) -> int:
    from capture.video import VideoSettings, record_video

    s = settings_from_args(VideoSettings, args)
    bars: list = []

    def calibrating(n: int = 1) -> None:  # a bar only when a fit is really needed
        if not bars:
            from tqdm import tqdm

            bars.append(
                tqdm(
                    desc="calibrating for this camera (once)",
                    unit="cell",
                    disable=args.quiet or None,
                    leave=False,
                    file=sys.stderr,
                )
            )
        bars[0].update(n)

    try:
        res = record_video(
            s, args.out, calibration_progress=calibrating, **_recording_options(args)
        )
    finally:
        for bar in bars:
            bar.close()
    rec = res.record
    _report_write_error(rec)
    if rec.write_error:
        return rec.exit_status
    if res.lost:
        _stderr(
            f"{PROG} video: note: {res.lost} frame(s) lost inside the source (first: "
            f"{res.first_loss}); each is a decode_error event in the recording"
        )
    if res.decode_error:
        _stderr(
            f"{PROG} video: note: decoding stopped after {rec.frames} frames "
            f"({res.decode_error}); the recording keeps every frame before it"
        )
    cal = res.calibration
    print(
        f"wrote {rec.path} ({rec.frames} frames, {res.repeats} repeated, {res.dropped} dropped; "
        f"calibration a={cal['a']:.5g}, b={cal['b']:.4g} ({cal['source']}, "
        f"{100 * cal['rms_rel_error']:.1f} % RMS); {rec.size_mb:.1f} MB, {rec.wall_time_s:.1f} s)"
    )
    return rec.exit_status


def cmd_sweep(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from capture.sweep import CaptureSweepSettings, capture_sweep

    where = {k: getattr(args, k) for k in ("executor", "jobs", "scheduler")}
    settings = CaptureSweepSettings(
        grid=tuple(args.grid), force=args.force, **{k: v for k, v in where.items() if v is not None}
    )
    total = len(settings.runs())
    # disable=None: a bar on terminals, silence in pipes and CI logs
    with tqdm(total=total, desc="sweep", unit="run", disable=True if args.quiet else None) as bar:
        res = capture_sweep(settings, args.out, progress=bar.update, log=_stderr)
    ran = len(res.outcomes) - len(res.failures)
    print(
        f"{res.planned} runs: {res.skipped} already done, {ran} recorded, "
        f"{len(res.failures)} failed ({res.elapsed_s:.1f} s)"
    )
    if res.paths:
        print(f"runs table: {res.files.runs} ({res.runs.height} rows)")
    for key, error in res.failures:
        print(f"  FAILED {key}: {error}", file=sys.stderr)
    return 1 if res.failures else 0


def add_output_options(p: argparse.ArgumentParser, default: str) -> None:
    """--out, --force, --spawn / --connect and --quiet: the same on every capture command."""
    p.add_argument("--out", help=f"output .rrd (default: {default})")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file")
    live = p.add_mutually_exclusive_group()
    live.add_argument(
        "--spawn",
        action="store_true",
        help="also stream to a new Rerun viewer (listening on 127.0.0.1)",
    )
    live.add_argument(
        "--connect",
        metavar="URL",
        help="also stream to a running viewer, e.g. rerun+http://127.0.0.1:9876/proxy",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


# each sub-command's settings dataclass: the one source of its flags' defaults
SETTINGS = {
    "sim": "capture.sim:SimSettings",
    "video": "capture.video:VideoSettings",
    "robot": "capture.robot_capture:RobotSettings",
    "emulate-robot": "capture.colias_link:EmulateSettings",
    "sweep": "capture.sweep:CaptureSweepSettings",
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser, with the settings of ``command`` bound (see ``bind_commands``)."""
    parser = OneLineParser(
        prog=PROG,
        description="Record runs of the arena as Rerun .rrd files (open them with `rerun FILE`).",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", parser_class=OneLineParser)
    sim = sub.add_parser(
        "sim",
        help="simulate the arena and a Colias-IV robot (no hardware needed)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Simulate the paper's arena (1.4 x 0.8 m, LED walls 0.15 m high, white light ring) "
            "and a Colias-IV robot driving at 0.08 m/s and turning 80-100 deg at the ring. The "
            "robot's 99x72 camera is rendered at 33 Hz, the online model runs on every frame, "
            "and everything is written to a Rerun recording with a default blueprint. "
            "The same seed gives the same frames and poses. Ctrl-C stops cleanly."
        ),
        epilog="examples:\n"
        "  vdc-capture sim --tf-hz 3 --minutes 30 --seed 1\n"
        "  vdc-capture sim --tf-schedule 0:30m,3:30m --out recordings/two-phase.rrd\n"
        "  vdc-capture sim --scene natural --tf-hz 3 --minutes 5 --spawn\n\n"
        "models:\n" + describe_models(),
    )
    sim.add_argument(
        "--scene",
        choices=["grating", "natural"],
        help="what the walls show (default: %(default)s)",
    )
    sim.add_argument(
        "--period-m",
        type=positive_float,
        help="grating period along the wall, m; a natural scene drifts at "
        "TF x this (default: %(default)s)",
    )
    tf = sim.add_mutually_exclusive_group()
    tf.add_argument(
        "--tf-hz",
        type=_non_negative_float,
        help="wall drift temporal frequency, Hz (default: %(default)s)",
    )
    tf.add_argument(
        "--tf-schedule",
        metavar="S",
        help="TF over time as TF:DURATION,... with s, m or h, e.g. 0:30m,3:30m",
    )
    sim.add_argument(
        "--minutes", type=positive_float, help="run length (default: 30, or the schedule's total)"
    )
    sim.add_argument("--seed", type=_seed, help="random seed (default: 0)")
    sim.add_argument(
        "--behaviour",
        choices=["profile", "collision"],
        help="profile: ring turns, online AVDM (default); collision: the robot "
        "avoids walls with an on-board LGMD detector, ring off, wall contact = crash",
    )
    sim.add_argument(
        "--model",
        help="online model (default: avdm); in collision mode the "
        "detector, lgmd-plus (default) or lgmd-colias",
    )
    sim.add_argument(
        "--profile-model",
        help="collision mode: the complexity model running alongside (default: %(default)s)",
    )
    sim.add_argument(
        "--threshold",
        type=positive_float,
        help="collision mode: alert threshold (lgmd-plus: spikes/s, default 56; "
        "lgmd-colias: consecutive spikes, default 4)",
    )
    sim.add_argument(
        "--adaptive",
        action="store_true",
        help="collision mode, lgmd-plus: let its FFI threshold T_ffi follow the on-board "
        "AVDM's running mean response (beyond the paper)",
    )
    sim.add_argument(
        "--adaptive-gain",
        type=_non_negative_float,
        help="collision mode: T_ffi = max(12, gain x mean AVDM deg/s over the last 60 s) "
        "(default: 1)",
    )
    sim.add_argument("--phase", help="collision mode: a label for the study's tables")
    sim.add_argument(
        "--contrast",
        type=positive_float,
        help="wall pattern contrast, 0-1 (default: %(default)s)",
    )
    sim.add_argument("--image", metavar="PATH", help="natural-scene wall from an image file")
    sim.add_argument(
        "--noise-sd",
        type=_non_negative_float,
        help="camera noise, 8-bit levels (default: 0)",
    )
    sim.add_argument("--overhead", action="store_true", help="also log an overhead camera")
    sim.add_argument(
        "--overhead-fps",
        type=positive_float,
        help="overhead camera rate, Hz (default: %(default)s)",
    )
    add_output_options(sim, "recordings/<run id>.rrd")
    sim.set_defaults(func=cmd_sim)
    em = sub.add_parser(
        "emulate-robot",
        help="a simulated Colias-IV on a pseudo-terminal, speaking the serial protocol",
        description=(
            "Open a pseudo-terminal behind --link, print it, wait for the host's START and "
            "stream frames and on-board AVDM outputs from the simulator with the protocol of "
            "the README; fault injection for testing the link."
        ),
    )
    em.add_argument(
        "--link",
        help="stable path (symlink) to the emulated port (default: %(default)s)",
    )
    em.add_argument("--tf-hz", type=_non_negative_float, help="wall TF, Hz")
    em.add_argument("--minutes", type=positive_float, help="run length")
    em.add_argument("--seed", type=_seed, help="random seed")
    em.add_argument(
        "--corrupt-rate",
        type=_non_negative_float,
        help="share of packets corrupted, e.g. 0.01 (1-3 bits flipped in each)",
    )
    em.add_argument(
        "--drop-rate",
        type=_non_negative_float,
        help="probability of dropping each packet",
    )
    em.add_argument(
        "--disconnect-after",
        type=positive_float,
        help="close the port once, this many seconds after START",
    )
    em.add_argument(
        "--reconnect-after",
        type=positive_float,
        help="seconds until the port reappears (default: %(default)s)",
    )
    em.add_argument(
        "--decimation", type=int, help="send the image with every Nth frame (slow links)"
    )
    em.add_argument("--fast", action="store_true", help="do not pace frames at 33 Hz")
    em.add_argument(
        "--wait",
        type=positive_float,
        help="seconds to wait for the host (default: %(default)s)",
    )
    em.add_argument("--report", help="write what was injected to this JSON file")
    em.set_defaults(func=cmd_emulate_robot)

    ro = sub.add_parser(
        "robot",
        help="record a real Colias-IV: serial link + overhead tracker (same recording contract)",
        description=(
            "Read frames and on-board model outputs from the robot's serial port and poses "
            "from an overhead camera with ArUco markers (ids 0-3 at the arena corners, 10 on "
            "the robot), join them on capture_time, and write the recording contract's "
            "entities. Ctrl-C or SIGTERM stops cleanly."
        ),
    )
    ro.add_argument("--port", required=True, help="the robot's serial device")
    ro.add_argument(
        "--camera",
        required=True,
        help="overhead camera: a device index, a video file or an image sequence "
        "such as frames/%%05d.png",
    )
    ro.add_argument(
        "--calibration",
        help="saved tracker homography (default: calibrate on the first overhead frame)",
    )
    ro.add_argument(
        "--camera-fps",
        type=positive_float,
        help="pace of a video file or image sequence (default: %(default)s)",
    )
    tfr = ro.add_mutually_exclusive_group()
    tfr.add_argument("--tf-hz", type=_non_negative_float, help="wall TF, Hz")
    tfr.add_argument(
        "--tf-schedule",
        metavar="S",
        help="e.g. 0:30m,3:30m, or a file with one TF:DURATION per line",
    )
    ro.add_argument(
        "--save-calibration",
        metavar="FILE",
        help="save the tracker's homography (calibrated on the first frame)",
    )
    ro.add_argument("--period-m", type=positive_float, help="wall period, m")
    ro.add_argument(
        "--scene",
        choices=["grating", "natural"],
    )
    ro.add_argument("--wall-port", help="LED wall controller's serial port (line protocol)")
    ro.add_argument("--baud", type=int, help="serial rate (default: 3000000)")
    ro.add_argument("--model", help="the model running on the robot")
    add_output_options(ro, "recordings/robot-<time>.rrd")
    ro.set_defaults(func=cmd_robot)

    vi = sub.add_parser(
        "video",
        help="profile any video file, image sequence or camera (true timestamps)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Decode SOURCE with its true presentation timestamps (variable frame rates and "
            "rotation metadata honoured), convert it to luma at the angular resolution the "
            "models were calibrated for, detect repeated and dropped frames, and run the AVDM "
            "on the new frames over true time. The decoding is calibrated for the source's "
            "frame rate and angular resolution on first use (cached per user). A camera index "
            "records until Ctrl-C."
        ),
        epilog="examples:\n"
        "  vdc-capture video clip.mp4 --fov-deg 66 --out recordings/clip.rrd\n"
        "  vdc-capture video 'frames/%05d.png' --fps 25 --fov-deg 90\n"
        "  vdc-capture video 0 --fov-deg 60 --spawn       # a webcam, live\n",
    )
    vi.add_argument(
        "source", help="a video file, an image sequence such as frames/%%05d.png, or a camera index"
    )
    vi.add_argument(
        "--fov-deg",
        type=positive_float,
        required=True,
        help="the camera's horizontal field of view, degrees",
    )
    vi.add_argument(
        "--fps", type=positive_float, help="frame rate of an image sequence (or a camera), Hz"
    )
    vi.add_argument(
        "--width",
        type=int,
        help="working width, px (default: fov / (70/99 deg), the robot camera's pitch)",
    )
    vi.add_argument(
        "--model",
        help="the model to run (default: %(default)s, the AVDM valid 1-300 deg/s on real "
        "footage; avdm is the paper's, valid up to about 1 px of motion per frame)",
    )
    vi.add_argument(
        "--repeat-tol",
        type=_non_negative_float,
        help="a frame whose mean |difference| from the previous is at most this (8-bit "
        "levels) repeats it (default: %(default)s)",
    )
    vi.add_argument(
        "--max-repeats",
        type=int,
        help="longer still stretches are a still scene, not repeats (default: %(default)s)",
    )
    add_output_options(vi, "recordings/video-<name>-<hash>.rrd")
    vi.set_defaults(func=cmd_video)

    sw = sub.add_parser(
        "sweep",
        help="a grid of simulated runs (a campaign), on all cores or a Dask cluster",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Record one simulated run per point of a grid over `vdc-capture sim`'s settings. "
            "Each GRID item is FIELD=V1,V2,... (a sim flag name; integers also as A..B); "
            "items with one value apply to every run, the runs are the product of the rest. "
            "Every run is one task: it writes OUT/recordings/<key>.rrd, then its row "
            "OUT/runs/<key>.parquet. A re-run records only runs without a row (--force: "
            "all); a failed run is listed and does not stop the others (exit status 1). "
            "At the end the rows become OUT/runs.parquet."
        ),
        epilog="examples:\n"
        "  vdc-capture sweep behaviour=collision model=lgmd-plus-arena minutes=30 "
        "threshold=40,56,80 tf_hz=0,1,3 seed=1..5\n"
        "  vdc-capture sweep tf_hz=0,1,3 seed=1..3 minutes=5 --executor dask "
        "--scheduler tcp://head:8786\n"
        "  vdc-analyse batch results/capture-sweep/recordings/*.rrd --model avdm --model "
        "avdm:beta=0.5\n\n"
        "models:\n" + describe_models(),
    )
    sw.add_argument("grid", nargs="+", metavar="GRID", help="FIELD=V1,V2,... (see above)")
    sw.add_argument(
        "--out", default="results/capture-sweep", help="output folder (default: %(default)s)"
    )
    sw.add_argument("--force", action="store_true", help="record finished runs again")
    sw.add_argument("--quiet", action="store_true", help="no progress bar")
    add_executor_options(sw, "simulated runs")
    sw.set_defaults(func=cmd_sweep)
    bind_commands(sub, SETTINGS, command)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser(command_of(argv, SETTINGS))
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        return args.func(args)
    except (UserError, ValueError) as exc:
        fail(f"{PROG} {args.command}", str(exc))
    except OSError as exc:
        fail(f"{PROG} {args.command}", f"{exc.strerror or exc}: {exc.filename or ''}".rstrip(": "))
    except LinkLost as exc:  # the recording was closed cleanly with everything received
        print(
            f"{PROG} {args.command}: error: {exc}; the recording holds every frame received before",
            file=sys.stderr,
        )
        return 1
