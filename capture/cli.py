"""``vdc-capture``: record runs of the arena as Rerun ``.rrd`` files."""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from avdm.cli_support import OneLineParser, UserError, fail, positive_float
from avdm.registry import describe_models
from capture.colias_link import LinkLost

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


def check_output_path(path: Path, force: bool) -> None:
    """Refuse to overwrite (unless ``force``) and make sure the folder is writable, before
    anything is rendered; raises UserError with the fix."""
    if path.suffix != ".rrd":
        raise UserError(f"output {str(path)!r} must end in .rrd")
    if path.is_dir():
        raise UserError(f"output {str(path)!r} is a directory; give a file name ending in .rrd")
    if path.exists() and not force:
        raise UserError(
            f"{str(path)!r} already exists (same configuration recorded before?): "
            "pass --force to record it again, or choose --out"
        )
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create the folder {str(path.parent)!r}: {exc.strerror}") from None
    if not os.access(path.parent, os.W_OK):
        raise UserError(f"the folder {str(path.parent)!r} is not writable")


def sim_config_from_args(args: argparse.Namespace):  # -> SimConfig
    from capture.config import (
        ArenaConfig,
        CameraConfig,
        CollisionConfig,
        OverheadConfig,
        RobotConfig,
        SimConfig,
        WallConfig,
        parse_schedule,
    )

    if args.tf_schedule is not None:
        schedule = parse_schedule(args.tf_schedule)
        total = sum(d for _, d in schedule)
        duration = args.minutes * 60 if args.minutes is not None else total
    else:
        duration = (args.minutes if args.minutes is not None else 30.0) * 60
        schedule = ((args.tf_hz, duration),)
    if args.image and args.scene != "natural":
        raise UserError("--image gives a natural scene: use it with --scene natural")
    wall = WallConfig(
        scene=args.scene,
        period_m=args.period_m,
        contrast=args.contrast,
        tf_schedule=schedule,
        nominal_period_m=args.period_m,
        image_path=args.image or "",
    )
    collision = args.behaviour == "collision"
    if collision:
        detector = args.model or "lgmd-plus"  # validated by CollisionConfig
        col = CollisionConfig(
            detector=detector,
            threshold=args.threshold if args.threshold is not None else float("nan"),
            adaptive=args.adaptive,
            adaptive_gain=args.adaptive_gain,
            phase=args.phase or "",
        )
        model = args.profile_model
    else:
        for flag, given in (
            ("--threshold", args.threshold is not None),
            ("--adaptive", args.adaptive),
            ("--phase", bool(args.phase)),
        ):
            if given:
                raise UserError(f"{flag} belongs to --behaviour collision")
        col = CollisionConfig()
        model = args.model or "avdm"
    return SimConfig(
        arena=ArenaConfig(ring_enabled=not collision),
        wall=wall,
        robot=RobotConfig(),
        camera=CameraConfig(noise_sd=args.noise_sd),
        overhead=OverheadConfig(enabled=args.overhead, fps=args.overhead_fps),
        duration_s=duration,
        seed=args.seed,
        model=model,
        behaviour=args.behaviour,
        collision=col,
    )


def cmd_sim(args: argparse.Namespace) -> int:
    from avdm.registry import make_model
    from capture.collision import CONTROLLER, CONTROLLER_OUTPUTS, ClosedLoopRobot
    from capture.recorder import Recorder, default_blueprint, model_path, spawn_viewer
    from capture.run import run_capture
    from capture.sim import SimulatedRobot, recording_properties

    config = sim_config_from_args(args)
    ctx = config.camera.model_context()
    model = make_model(config.model, **ctx)
    collision = config.behaviour == "collision"
    detector = make_model(config.collision.detector_spec(), **ctx) if collision else None
    # the device reads a wall image now, so a bad one fails before anything is written
    device = ClosedLoopRobot(config) if collision else SimulatedRobot(config)
    run_id = config.run_id()
    out = Path(args.out) if args.out else Path("recordings") / f"{run_id}.rrd"
    check_output_path(out, args.force)
    live = spawn_viewer() if args.spawn else args.connect
    if detector is not None:
        main = detector
        extra = [
            ("AVDM omega_dps (deg/s), on board", [model_path(model.name, "omega_dps")]),
            (
                "spike rate and alert threshold (spikes/s)",
                [model_path(CONTROLLER, "threshold"), model_path(detector.name, "spike_rate_hz")],
            ),
            (
                "FFI and its threshold T_ffi in force",
                [model_path(CONTROLLER, "t_ffi"), model_path(detector.name, "ffi")],
            ),
        ]
    else:
        main, extra = model, []
    recorder = Recorder(
        out, run_id, blueprint=default_blueprint(main.name, main.outputs, extra), live_url=live
    )
    recorder.send_properties(recording_properties(config, model, detector))
    recorder.log_arena(config.arena, config.robot.radius_m)
    recorder.log_model_meta(model.name, model.outputs)
    if detector is not None:
        from avdm.base import Output

        recorder.log_model_meta(detector.name, detector.outputs)
        recorder.log_model_meta(
            CONTROLLER, tuple(Output(k, u, d) for k, (u, d) in CONTROLLER_OUTPUTS.items())
        )
    minutes = config.duration_s / 60
    what = (
        f"collision mode, detector {detector.name}"
        + (" (adaptive threshold)" if config.collision.adaptive else "")
        if detector
        else f"model {model.name}"
    )
    print(
        f"recording {run_id}: {config.wall.scene} walls, TF schedule "
        f"{config.to_sections()['wall']['tf_schedule_text']}, {minutes:g} min "
        f"({config.n_frames} frames at {config.camera.fps:g} Hz), {what}",
        file=sys.stderr,
    )
    result = run_capture(
        device,
        None if collision else model,
        recorder,
        total_frames=config.n_frames,
        progress=not args.quiet,
    )
    size_mb = out.stat().st_size / 1e6
    if result.stop_reason == "finished":
        events = ", ".join(f"{n} {k.replace('_', ' ')}s" for k, n in sorted(result.events.items()))
        print(
            f"wrote {out} ({result.frames} frames, {events or 'no events'}, {size_mb:.0f} MB, "
            f"{result.wall_time_s:.1f} s)"
        )
        return 0
    print(
        f"stopped by {result.stop_reason} after {result.frames} of {config.n_frames} frames; "
        f"{out} is a valid recording of those frames ({size_mb:.0f} MB)"
    )
    return 130 if "SIGINT" in result.stop_reason else 143


def cmd_emulate_robot(args: argparse.Namespace) -> int:
    from capture.colias_link import EmulatorConfig, RobotEmulator
    from capture.config import CameraConfig, SimConfig, WallConfig

    emu = EmulatorConfig(
        corrupt_rate=args.corrupt_rate,
        drop_rate=args.drop_rate,
        disconnect_after_s=args.disconnect_after if args.disconnect_after else float("nan"),
        reconnect_after_s=args.reconnect_after,
        decimation=args.decimation,
        realtime=not args.fast,
        seed=args.seed,
    )
    sim = SimConfig(
        wall=WallConfig(tf_schedule=((args.tf_hz, args.minutes * 60),)),
        camera=CameraConfig(),
        duration_s=args.minutes * 60,
        seed=args.seed,
    )
    link = Path(args.link)
    robot = RobotEmulator(sim, emu, link, Path(args.report) if args.report else None)

    def announce(device: str) -> None:
        print(
            f"emulated Colias-IV on {device} (also {link}); waiting for the host's START",
            flush=True,
        )

    try:
        report = robot.run(wait_for_host_s=args.wait, announce=announce)
    except TimeoutError as exc:
        raise UserError(str(exc)) from None
    print(
        f"sent {len(report['intact'])} intact and {len(report['corrupted'])} corrupted "
        f"frames; dropped {len(report['dropped'])}; {len(report['lost_in_disconnect'])} "
        f"lost in {report['disconnects']} disconnect(s)"
    )
    return 0


class WallController:
    """Optional LED wall controller on a second serial port; a line protocol (ASCII, \\n):
    ``TF <hz> PERIOD <m> SCENE <grating|natural>`` whenever the TF in force changes."""

    def __init__(self, port: str, wall) -> None:  # wall: WallConfig
        import serial

        try:
            self.ser = serial.Serial(port, 115200, timeout=0.1)
        except (serial.SerialException, OSError) as exc:
            raise UserError(
                f"cannot open the wall controller port {port!r}: "
                f"{getattr(exc, 'strerror', None) or exc}"
            ) from None
        self.wall = wall
        self.last: float | None = None

    def update(self, tf_hz: float) -> None:
        if tf_hz != self.last:
            line = f"TF {tf_hz:.3f} PERIOD {self.wall.drift_period_m:.4f} SCENE {self.wall.scene}\n"
            self.ser.write(line.encode("ascii"))
            self.ser.flush()
            self.last = tf_hz


def cmd_robot(args: argparse.Namespace) -> int:
    import hashlib
    import time as _time

    from capture.config import WallConfig, parse_schedule
    from capture.recorder import Recorder, default_blueprint, spawn_viewer
    from capture.robot_capture import LINK_STATS, ColiasRobotDevice, RobotCaptureConfig
    from capture.run import run_capture
    from contract.provenance import machine_info, package_versions

    schedule: tuple[tuple[float, float], ...] = ((args.tf_hz, 48 * 3600.0),)
    if args.tf_schedule:
        text = args.tf_schedule
        if Path(text).is_file():  # a schedule file: the same syntax, one segment a line
            lines = Path(text).read_text().splitlines()
            text = ",".join(ln.strip() for ln in lines if ln.strip() and ln.strip()[0] != "#")
        schedule = parse_schedule(text)
    wall = WallConfig(tf_schedule=schedule, period_m=args.period_m, scene=args.scene)
    cfg = RobotCaptureConfig(
        port=args.port,
        camera=args.camera,
        baud=args.baud,
        calibration=args.calibration or "",
        camera_fps=args.camera_fps,
        wall=wall,
        model=args.model,
    )
    wall_ctl = WallController(args.wall_port, wall) if args.wall_port else None
    device = ColiasRobotDevice(cfg, on_wall_tf=wall_ctl.update if wall_ctl else None)
    stamp = _time.strftime("%Y%m%d-%H%M%S")
    rid = (
        f"robot-{stamp}-"
        + hashlib.sha1(f"{args.port}{args.camera}{stamp}".encode()).hexdigest()[:8]
    )
    out = Path(args.out) if args.out else Path("recordings") / f"{rid}.rrd"
    check_output_path(out, args.force)
    device.connect()  # a missing port or camera fails here, before the file exists
    live = spawn_viewer() if args.spawn else args.connect
    from avdm.registry import make_model

    model = make_model(args.model, fps=cfg.fps, deg_per_px=cfg.deg_per_px)
    from capture.config import ArenaConfig, RobotConfig
    from capture.recorder import LINK_STATS as LINK_STATS_ENTITY

    recorder = Recorder(
        out,
        rid,
        live_url=live,
        blueprint=default_blueprint(
            model.name, model.outputs, [("serial link counts", [LINK_STATS_ENTITY])]
        ),
    )
    recorder.log_arena(ArenaConfig(), RobotConfig().radius_m)
    recorder.send_properties(
        {
            "run": {
                "recording_id": rid,
                "source": "robot",
                "port": args.port,
                "baud": args.baud,
                "camera": args.camera,
                "behaviour": "robot",
            },
            "wall": {
                "scene": wall.scene,
                "period_m": wall.period_m,
                "tf_schedule_text": ",".join(f"{t:g}:{d:g}s" for t, d in schedule),
            },
            "camera": {"fps": cfg.fps, "width_px": 99, "height_px": 72, "hfov_deg": 70.0},
            "model": {"name": model.name, "on_board": True},
            "model_params": model.params.to_dict(),
            "link": {"protocol": "vdc serial v1 (see README)", "stats": ",".join(LINK_STATS)},
            "provenance": {**package_versions(), **machine_info()},
        }
    )
    recorder.log_model_meta(model.name, model.outputs)
    if args.save_calibration:
        from capture.tracker import save_calibration

        device._poll_camera()
        if device.h is None:
            raise UserError("no overhead frame yet to calibrate from")
        save_calibration(device.h, Path(args.save_calibration))
    print(
        f"recording {rid} from {args.port} (overhead camera {args.camera}) -> {out}",
        file=sys.stderr,
    )
    result = run_capture(device, None, recorder, total_frames=None, progress=not args.quiet)
    stats = device.link_stats()
    print(
        f"wrote {out}: {result.frames} frames, link: "
        + ", ".join(f"{k} {v}" for k, v in stats.items())
        + f" ({result.stop_reason})"
    )
    return (
        0 if result.stop_reason == "finished" else (130 if "SIGINT" in result.stop_reason else 143)
    )


def build_parser() -> argparse.ArgumentParser:
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
        default="grating",
        help="what the walls show (default: %(default)s)",
    )
    sim.add_argument(
        "--period-m",
        type=positive_float,
        default=0.1,
        help="grating period along the wall, m; a natural scene drifts at "
        "TF x this (default: %(default)s)",
    )
    tf = sim.add_mutually_exclusive_group()
    tf.add_argument(
        "--tf-hz",
        type=_non_negative_float,
        default=0.0,
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
    sim.add_argument("--seed", type=_seed, default=0, help="random seed (default: 0)")
    sim.add_argument(
        "--behaviour",
        choices=["profile", "collision"],
        default="profile",
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
        default="avdm",
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
        default=1.0,
        help="collision mode: T_ffi = max(12, gain x mean AVDM deg/s over the last 60 s) "
        "(default: 1)",
    )
    sim.add_argument("--phase", help="collision mode: a label for the study's tables")
    sim.add_argument(
        "--contrast",
        type=positive_float,
        default=1.0,
        help="wall pattern contrast, 0-1 (default: %(default)s)",
    )
    sim.add_argument("--image", metavar="PATH", help="natural-scene wall from an image file")
    sim.add_argument(
        "--noise-sd",
        type=_non_negative_float,
        default=0.0,
        help="camera noise, 8-bit levels (default: 0)",
    )
    sim.add_argument("--out", help="output .rrd (default: recordings/<run id>.rrd)")
    sim.add_argument("--force", action="store_true", help="overwrite an existing output file")
    sim.add_argument("--overhead", action="store_true", help="also log an overhead camera")
    sim.add_argument(
        "--overhead-fps",
        type=positive_float,
        default=5.0,
        help="overhead camera rate, Hz (default: %(default)s)",
    )
    live = sim.add_mutually_exclusive_group()
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
    sim.add_argument("--quiet", action="store_true", help="no progress bar")
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
        default="/tmp/vdc-robot",
        help="stable path (symlink) to the emulated port (default: %(default)s)",
    )
    em.add_argument("--tf-hz", type=_non_negative_float, default=0.0, help="wall TF, Hz")
    em.add_argument("--minutes", type=positive_float, default=1.0, help="run length")
    em.add_argument("--seed", type=_seed, default=0, help="random seed")
    em.add_argument(
        "--corrupt-rate",
        type=_non_negative_float,
        default=0.0,
        help="share of packets corrupted, e.g. 0.01 (1-3 bits flipped in each)",
    )
    em.add_argument(
        "--drop-rate",
        type=_non_negative_float,
        default=0.0,
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
        default=1.0,
        help="seconds until the port reappears (default: %(default)s)",
    )
    em.add_argument(
        "--decimation", type=int, default=1, help="send the image with every Nth frame (slow links)"
    )
    em.add_argument("--fast", action="store_true", help="do not pace frames at 33 Hz")
    em.add_argument(
        "--wait",
        type=positive_float,
        default=60.0,
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
        default=10.0,
        help="pace of a video file or image sequence (default: %(default)s)",
    )
    tfr = ro.add_mutually_exclusive_group()
    tfr.add_argument("--tf-hz", type=_non_negative_float, default=0.0, help="wall TF, Hz")
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
    ro.add_argument("--period-m", type=positive_float, default=0.1, help="wall period, m")
    ro.add_argument("--scene", choices=["grating", "natural"], default="grating")
    ro.add_argument("--wall-port", help="LED wall controller's serial port (line protocol)")
    ro.add_argument("--baud", type=int, default=3_000_000, help="serial rate (default: 3000000)")
    ro.add_argument("--model", default="avdm", help="the model running on the robot")
    ro.add_argument("--out", help="output .rrd (default: recordings/robot-<time>.rrd)")
    ro.add_argument("--force", action="store_true", help="overwrite an existing output file")
    rlive = ro.add_mutually_exclusive_group()
    rlive.add_argument("--spawn", action="store_true", help="also stream to a new viewer")
    rlive.add_argument("--connect", metavar="URL", help="also stream to a running viewer")
    ro.add_argument("--quiet", action="store_true", help="no progress bar")
    ro.set_defaults(func=cmd_robot)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
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
