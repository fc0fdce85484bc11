"""The serial protocol, the robot emulator on a real pseudo-terminal, and robot capture."""

from __future__ import annotations

import json
import os
import pty
import select
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from analysis.recordings.reader import Recording
from capture.config import SimConfig, WallConfig
from capture.render import OverheadRenderer
from capture.robot_capture import WallController
from capture.serial_protocol import (
    TYPE_END,
    TYPE_FRAME,
    PacketParser,
    crc16,
    decode_frame,
    encode,
    encode_frame,
)
from capture.sim_robot import SimulatedRobot
from capture.tracker import calibrate_homography as tracker_calibrate
from capture.tracker import load_calibration as tracker_load
from capture.tracker import robot_pose as tracker_pose
from tests.helpers import (
    ROOT,
    assert_file_grows,
    assert_one_line_error,
    run_cli,
    spawn,
    start_emulator,
    wait_until,
)
from vdc.recording import partial_path


def test_crc_is_ccitt_false() -> None:
    assert crc16(b"123456789") == 0x29B1


frame_args = st.tuples(
    st.integers(0, 2**32 - 1),
    st.integers(0, 2**63 - 1),
    st.lists(st.floats(-1e6, 1e6, width=32), max_size=8),
    st.booleans(),
    st.integers(1, 12),
    st.integers(1, 12),
)


@given(frame_args)
def test_frames_round_trip(args) -> None:
    index, t_us, outputs, with_image, h, w = args
    image = np.arange(h * w, dtype=np.uint8).reshape(h, w) if with_image else None
    packet = encode_frame(index, t_us, outputs, image, (h, w))
    ((ptype, payload),) = list(PacketParser().feed(packet))
    assert ptype == TYPE_FRAME
    f = decode_frame(payload)
    assert (f.index, f.robot_time_us, f.width, f.height) == (index, t_us, w, h)
    assert f.outputs == tuple(
        struct.unpack(f"<{len(outputs)}f", struct.pack(f"<{len(outputs)}f", *outputs))
    )
    assert (f.image is None) == (image is None)
    if image is not None:
        assert np.array_equal(f.image, image)


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 12),
    garbage=st.lists(st.binary(max_size=40), min_size=13, max_size=13),
    corrupt=st.lists(st.booleans(), min_size=12, max_size=12),
    cuts=st.lists(st.integers(1, 500), max_size=30),
    seed=st.integers(0, 2**16),
)
def test_parser_resynchronises_and_never_yields_corrupt_data(
    n, garbage, corrupt, cuts, seed
) -> None:
    rng = np.random.default_rng(seed)
    stream = bytearray(garbage[0])
    good = []
    for i in range(n):
        img = rng.integers(0, 256, (6, 7), dtype=np.uint8)
        pkt = bytearray(encode_frame(i, i * 30_000, [float(i)], img, (6, 7)))
        if corrupt[i]:
            k = int(rng.integers(4, len(pkt)))  # past the sync word: a damaged body
            pkt[k] ^= 1 << int(rng.integers(8))
        else:
            good.append(i)
        stream += pkt + garbage[i + 1]
    parser = PacketParser()
    got, pos = [], 0
    for cut in [*cuts, len(stream)]:  # arbitrary read sizes
        chunk = bytes(stream[pos : pos + cut])
        pos += cut
        got += [decode_frame(p).index for t, p in parser.feed(chunk) if t == TYPE_FRAME]
        if pos >= len(stream):
            break
    got += [decode_frame(p).index for t, p in parser.feed(bytes(stream[pos:])) if t == TYPE_FRAME]
    # garbage could, very rarely, hide one good packet behind a false sync: never invent one
    assert set(got) <= set(good)
    assert len(got) == len(set(got))
    assert len(good) - len(got) <= sum(1 for g in garbage if b"\xaa" in g)
    # every damaged packet is counted (a single flipped bit never passes the CRC-16, and a
    # flipped type byte fails the length check or the CRC) unless the stream ends while the
    # parser still waits for the body a false sync word in the garbage announced
    counted = parser.stats.bad_crc + parser.stats.bad_length
    assert counted >= sum(corrupt[:n]) - sum(1 for g in garbage if b"\xaa" in g)


def render_overhead(folder: Path, seconds: float, fps: float = 10.0, seed: int = 0) -> SimConfig:
    """The overhead camera's frames (ArUco markers) of the emulator's simulated run."""
    cfg = SimConfig(wall=WallConfig(tf_schedule=((0.0, seconds),)), duration_s=seconds, seed=seed)
    r = OverheadRenderer(cfg.arena, cfg.robot.radius_m, 1200.0, markers=True)
    with SimulatedRobot(cfg, batch_size=100_000) as dev:
        poses = dev.read().poses
    folder.mkdir(parents=True)
    for k, f in enumerate(overhead_frames(cfg, seconds, fps)):
        cv2.imwrite(str(folder / f"{k:05d}.png"), r.render(poses[f]))
    return cfg


@pytest.fixture(scope="module")
def overhead_20s(tmp_path_factory) -> Path:
    """The overhead frames of the emulator's 20-s run (seed 0), rendered once for the tests
    that only read them (7 s of a core each time)."""
    folder = tmp_path_factory.mktemp("overhead") / "overhead"
    render_overhead(folder, 20.0)
    return folder


def images_in(path: Path) -> int:
    """Frames with an image in a recording still being written (0 while it cannot be read)."""
    try:
        return len(Recording(path).read_frames().frame)
    except Exception:  # not created yet, or its first chunk is still being written
        return 0


def start_robot_capture(link: Path, frames: Path, out: Path, min_bytes: int) -> subprocess.Popen:
    """``vdc-capture robot`` in the background; returns once its partial file holds
    ``min_bytes`` (fails if it does not within 60 s)."""
    cap = spawn(
        [
            sys.executable,
            "-m",
            "capture",
            "robot",
            "--port",
            str(link),
            "--camera",
            str(frames / "%05d.png"),
            "--out",
            str(out),
            "--quiet",
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert_file_grows(cap, partial_path(out), min_bytes)  # where a capture writes until it ends
    return cap


def capture_robot(
    port: str | Path, camera: str | Path, out: Path, *extra: str, **run: Any
) -> subprocess.CompletedProcess:
    """``vdc-capture robot --port PORT --camera CAMERA --out OUT EXTRA`` in a subprocess."""
    argv = ["--port", str(port), "--camera", str(camera), "--out", str(out), *extra]
    return run_cli("capture", "robot", *argv, **run)


def test_end_to_end_on_a_pty_with_corruption_and_a_disconnect(tmp_path: Path) -> None:
    seconds = 12.0
    cfg = render_overhead(tmp_path / "overhead", seconds, seed=3)
    link, report_path, out = tmp_path / "robot", tmp_path / "report.json", tmp_path / "rec.rrd"
    emu = start_emulator(
        link,
        report_path,
        "--minutes",
        str(seconds / 60),
        "--corrupt-rate",
        "0.01",
        "--drop-rate",
        "0.01",
        "--disconnect-after",
        "5",
        "--reconnect-after",
        "1",
        "--seed",
        "3",
    )
    proc = capture_robot(link, tmp_path / "overhead" / "%05d.png", out, "--quiet", timeout=120)
    emu.wait(timeout=120)
    assert proc.returncode == 0, (
        proc.stderr + "\nemulator: " + emu.stdout.read() + emu.stderr.read()
    )
    report = json.loads(report_path.read_text())
    assert report["disconnects"] == 1 and report["corrupted"]
    rec = Recording(out)
    frames = rec.read_frames()
    got = frames.frame.tolist()
    intact = set(report["intact"])
    assert got == sorted(intact)  # every good frame exactly once, and nothing else
    with SimulatedRobot(cfg, batch_size=100_000) as dev:
        truth = dev.read()
    assert np.array_equal(frames.images, truth.images[got])  # bit-exact images
    # the link's counts match what was injected
    stats = rec.signals()["/link/stats"][2][-1]
    bad_crc, bad_length = stats[1], stats[2]
    lost, dup, disconnects = stats[4], stats[5], stats[6]
    assert bad_crc + bad_length == len(report["corrupted"]) > 0
    assert disconnects == 1 and dup == 0
    missing = len(report["corrupted"]) + len(report["dropped"]) + len(report["lost_in_disconnect"])
    assert lost == missing  # frame 0 is intact (corruption and drops start later by seed)
    kinds = set(rec.events()["kind"])
    assert "link_error" in kinds
    # poses: the host joins each frame to the overhead sample nearest its receive time, so
    # which image a frame meets depends on how late the emulator and the host ran (a loaded
    # machine sends seconds late). What must hold whatever the timing is counted: every
    # recorded frame has a pose or lies in a gap the host logged (one `tracker_lost` event
    # per run of frames without one), and every pose is the tracker's reading of one of the
    # overhead images it was given. The join and the turning flag on exact times:
    # test_the_tracker_joined_to_frames_flags_the_turns_the_simulator_made.
    f, _, poses = rec.poses()
    assert set(f.tolist()) <= set(got)
    posed = np.isin(got, f)
    gap_starts = int(np.sum(~posed & np.concatenate([[True], posed[:-1]])))
    lost_events = int(np.sum(np.asarray(rec.events()["kind"]) == "tracker_lost"))
    assert lost_events == gap_starts, (lost_events, gap_starts, int(posed.sum()))
    # the frames table (every table's spine) keeps every recorded frame, posed or not: a
    # frame the tracker missed has null poses, not a missing row (seen in CI at load 10,
    # where the first frames met no overhead image and `tables --model` lost them)
    from analysis.recordings.loading import load_recording

    table = load_recording(out).frames
    assert table["frame"].to_list() == got
    assert table["x_m"].is_not_null().to_numpy().tolist() == posed.tolist()
    shown = truth.poses[overhead_frames(cfg, seconds)]  # (K, 3): what the images show
    nearest = np.hypot(*(poses[:, None, :2] - shown[None, :, :2]).transpose(2, 0, 1)).min(axis=1)
    # the tracker reads a rendered pose within 5 mm (tests/capture/test_tracker.py)
    assert np.all(nearest < 0.005), nearest.max()
    timelines = {t for ch in rec._reader.store().stream() for t in ch.timeline_names}
    assert "capture_time" in timelines


def overhead_frames(cfg: SimConfig, seconds: float, fps: float = 10.0) -> np.ndarray:
    """The simulator frame each overhead image of ``render_overhead`` shows: (K,) int."""
    n_frames = round(seconds * cfg.camera.fps)
    k = np.arange(int(seconds * fps))
    return np.minimum(np.round(k * cfg.camera.fps / fps).astype(int), n_frames - 1)


def test_the_tracker_joined_to_frames_flags_the_turns_the_simulator_made() -> None:
    """The host's join (``ColiasRobotDevice._pose_at``: the overhead sample nearest a frame's
    receive time, none beyond ``max_gap_s``) on exact times: 10-Hz tracker poses read from
    rendered images, joined to 33-Hz frames, give the turning flag the simulator's exact
    poses give, frame for frame."""
    from types import SimpleNamespace

    from analysis.recordings.ego_motion import turning_flags, yaw_rate_dps
    from capture.robot_capture import ColiasRobotDevice

    seconds = 12.0
    cfg = SimConfig(wall=WallConfig(tf_schedule=((0.0, seconds),)), duration_s=seconds, seed=3)
    r = OverheadRenderer(cfg.arena, cfg.robot.radius_m, 1200.0, markers=True)
    with SimulatedRobot(cfg, batch_size=100_000) as dev:
        truth = dev.read()
    shown = overhead_frames(cfg, seconds)
    h = tracker_calibrate(r.render(truth.poses[0]), r.layout)
    samples = [
        (int(k * 1e8), tracker_pose(r.render(truth.poses[g]), h)) for k, g in enumerate(shown)
    ]
    host = SimpleNamespace(samples=samples, cfg=SimpleNamespace(max_gap_s=0.25))
    fps = cfg.camera.fps
    t_s = np.arange(len(truth.poses)) / fps
    joined = [ColiasRobotDevice._pose_at(host, int(t * 1e9)) for t in t_s]  # type: ignore[arg-type]
    assert all(p is not None for p in joined)  # the images span the run: no gap
    flags = turning_flags(yaw_rate_dps(t_s, np.array([p[2] for p in joined])))
    valid = ~np.isnan(flags)
    tracked = flags > 0.5
    expected = turning_flags(yaw_rate_dps(t_s, truth.poses[:, 2])) > 0.5
    assert expected[valid].sum() > 10 and (~expected[valid]).sum() > 10  # turns and straights
    # the 10-Hz tracker places a turn's edges to within ~1 of its frames (3 camera frames)
    assert (tracked[valid] == expected[valid]).mean() > 0.9


def test_decimated_images_and_sigkill_leave_a_readable_recording(
    tmp_path: Path, overhead_20s: Path
) -> None:
    link, report_path, out = tmp_path / "robot", tmp_path / "report.json", tmp_path / "rec.rrd"
    # a run far longer than the test: the kill must land mid-run however late a loaded
    # machine lets the test see the partial file grow (a 20-s run once ended first)
    emu = start_emulator(link, report_path, "--minutes", "10", "--decimation", "3")
    cap = start_robot_capture(link, overhead_20s, out, 200_000)
    # kill it mid-run, once its partial file holds more than 10 frames' images (no deadline
    # while it runs but the emulator's 10 minutes: a loaded machine only makes it slower)
    wait_until(lambda: images_in(partial_path(out)) > 10 or cap.poll() is not None, 540, 0.5)
    assert cap.poll() is None and images_in(partial_path(out)) > 10
    cap.send_signal(signal.SIGKILL)
    cap.wait(timeout=120)
    emu.kill()
    emu.wait(timeout=120)
    assert not out.exists()  # a killed capture never takes the final name...
    out = partial_path(out)  # ...its frames are in the partial file, readable as it is
    rec = Recording(out)
    frames = rec.read_frames()
    assert len(frames.frame) > 10 and (frames.frame % 3 == 0).all()  # every 3rd frame's image
    outputs = rec.model_outputs("avdm", ["omega_dps"])
    # outputs for every frame; seen once short under a loaded suite (images to frame 990,
    # outputs to 519): the message keeps what would tell where they were lost
    assert len(outputs["frame"]) >= 2 * len(frames.frame), (
        f"{len(outputs['frame'])} outputs to frame {outputs['frame'].max()} against "
        f"{len(frames.frame)} images to frame {frames.frame.max()}; file {out.stat().st_size} "
        f"bytes; capture stderr: {cap.stderr.read()[-2000:] if cap.stderr else ''!r}"
    )
    res = run_cli("analysis", "tables", str(out), "--out", str(tmp_path / "t"))
    assert res.returncode == 0, res.stderr


def test_missing_port_or_camera_is_one_line(tmp_path: Path) -> None:
    out = tmp_path / "x.rrd"
    assert_one_line_error(
        capture_robot("/dev/nonexistent-robot", "0", out),
        "serial port",
    )
    master, slave = pty.openpty()
    try:
        port = os.ttyname(slave)
        assert_one_line_error(
            capture_robot(port, tmp_path / "none.mp4", out),
            "overhead camera",
        )
    finally:
        os.close(master)
        os.close(slave)
    assert not out.exists()


def test_wall_controller_line_protocol() -> None:
    master, slave = pty.openpty()
    try:
        import tty

        tty.setraw(slave)
        ctl = WallController(os.ttyname(slave), WallConfig(period_m=0.1))
        ctl.update(0.0)
        ctl.update(0.0)  # unchanged: nothing sent
        ctl.update(3.0)
        sent = "TF 0.000 PERIOD 0.1000 SCENE grating\nTF 3.000 PERIOD 0.1000 SCENE grating\n"
        data = b""
        while len(data) < len(sent) and select.select([master], [], [], 10)[0]:
            data += os.read(master, 4096)  # until both lines arrived (or 10 s of silence)
        ctl.update(3.0)  # unchanged again: nothing more is sent
        assert data.decode() == sent and not select.select([master], [], [], 0)[0]
    finally:
        os.close(master)
        os.close(slave)


def test_host_commands_are_framed_packets() -> None:
    assert encode(0x10) == b"\xaa\x55\x01\x00\x10" + struct.pack("<H", crc16(b"\x01\x00\x10"))


@pytest.mark.parametrize("bad", [b"\xaa\x55\xff\xff", b"\xaa\x55\x00\x00"])
def test_absurd_lengths_are_skipped(bad: bytes) -> None:
    parser = PacketParser()
    good = encode_frame(1, 0, [1.0], None, (2, 2))
    got = list(parser.feed(bad + good))
    assert [decode_frame(p).index for _, p in got] == [1]
    assert parser.stats.bad_length >= 1


def test_schedule_file_and_saved_calibration(tmp_path: Path) -> None:
    render_overhead(tmp_path / "overhead", 4.0)
    schedule = tmp_path / "schedule.txt"
    schedule.write_text("# TF:duration\n0:2s\n3:10s\n")
    link, report_path, out = tmp_path / "robot", tmp_path / "report.json", tmp_path / "rec.rrd"
    emu = start_emulator(link, report_path, "--minutes", str(4 / 60))
    proc = capture_robot(
        link,
        tmp_path / "overhead" / "%05d.png",
        out,
        "--tf-schedule",
        str(schedule),
        "--save-calibration",
        str(tmp_path / "cal.json"),
        "--quiet",
        timeout=300,
    )
    emu.wait(timeout=120)
    assert proc.returncode == 0, proc.stderr
    _, _, tf = Recording(out).wall_tf()
    assert set(np.unique(tf)) <= {0.0, 3.0} and tf[-1, 0] == 3.0
    assert tracker_load(tmp_path / "cal.json").shape == (3, 3)


def test_sigint_stops_robot_capture_cleanly(tmp_path: Path, overhead_20s: Path) -> None:
    link, report_path, out = tmp_path / "robot", tmp_path / "report.json", tmp_path / "rec.rrd"
    emu = start_emulator(link, report_path, "--minutes", "10")  # ends with the host's STOP
    cap = start_robot_capture(link, overhead_20s, out, 300_000)
    cap.send_signal(signal.SIGINT)
    _, stderr = cap.communicate(timeout=120)
    emu.wait(timeout=120)  # the host's STOP ends the emulator's run
    assert cap.returncode == 130, stderr
    rec = Recording(out)
    assert rec.notice is None  # footer written
    end = rec.properties()["run_end"]
    assert end["stop_reason"] == "signal SIGINT" and end["frames"] > 10
    assert len(rec.read_frames().frame) == end["frames"]


def test_a_host_that_reads_late_still_gets_the_robots_end(tmp_path: Path) -> None:
    """The emulator closes its port only once the host has read END: closing a pty discards
    what the host has not read yet, and a host that misses END takes the vanished port for a
    cable pulled out and waits for the robot to come back (the flaky 'did not come back within
    30 s' of a loaded machine). Here the host does not read until the robot has sent its whole
    run (1 s of frames, without images, fits in the pty's buffers)."""
    import termios

    import serial

    from capture.robot_emulator import EmulateSettings, emulate_robot
    from capture.serial_protocol import TYPE_END, TYPE_START, TYPE_STOP

    link = tmp_path / "robot"
    settings = EmulateSettings(
        link=str(link), minutes=1 / 60, fast=True, decimation=1000, width_px=16, height_px=12
    )
    reports: list[dict] = []
    robot = threading.Thread(target=lambda: reports.append(emulate_robot(settings)))
    robot.start()
    try:
        assert wait_until(link.is_symlink, 300), "the emulator's port did not appear"
        host = serial.Serial(str(link), timeout=0.05)
        host.write(encode(TYPE_START))
        host.flush()
        # wait, reading nothing, until the robot has written all it will write (its run is
        # over: the bytes waiting stop growing for 1 s) or it closed the port
        sizes = [-1]

        def robot_done() -> bool:
            if not robot.is_alive():
                return True
            sizes.append(host.in_waiting)
            return len(sizes) > 20 and len(set(sizes[-21:])) == 1 and sizes[-1] > 0

        assert wait_until(robot_done, 300)
        parser, types = PacketParser(), []
        deadline = time.monotonic() + 30  # a loaded machine may write the last bytes late
        while TYPE_END not in types and time.monotonic() < deadline:
            try:
                data = host.read(4096)
            except serial.SerialException:  # the port was closed under the host
                break
            if not data and not robot.is_alive():
                break  # the robot is gone and nothing more is waiting
            types += [t for t, _ in parser.feed(data)]
        if TYPE_END in types:
            # as vdc's host answers END. The robot may close its port as soon as STOP arrives,
            # before this side's drain returns: the drain then fails (termios.error, EIO, seen
            # under load), which is the run's normal end, not a fault of the test's subject
            try:
                host.write(encode(TYPE_STOP))
                host.flush()
            except (serial.SerialException, OSError, termios.error):
                pass
        host.close()
    finally:
        robot.join(timeout=60)
    assert TYPE_END in types, "the robot closed its port before the host read its END"
    assert types.count(TYPE_FRAME) == reports[0]["frames"] == 33


def test_closing_a_link_whose_far_end_is_gone_raises_nothing() -> None:
    """pyserial's flush() on POSIX raises termios.error, which is not an OSError, once the pty's
    far end has closed; stopping the capture then must not end in a traceback (seen in CI)."""
    import termios

    from capture.serial_link import SerialLink

    master, slave = pty.openpty()
    try:
        link = SerialLink(os.ttyname(slave), 115200, 1.0)
        link.open()
        os.close(master)
        master = -1
        bad_fd = os.open(os.devnull, os.O_RDONLY)
        os.close(bad_fd)
        with pytest.raises(termios.error):  # the error itself, from a real tcdrain
            termios.tcdrain(bad_fd)
        # the moment in CI: the STOP was written, then tcdrain failed
        link._ser.flush = lambda: termios.tcdrain(bad_fd)  # type: ignore[union-attr]
        link.close(stop=True)
        assert link._ser is None
    finally:
        if master >= 0:
            os.close(master)
        os.close(slave)


def _stream_with_a_damaged_length_before_end() -> tuple[bytes, int]:
    """Two frames, a third whose length field was hit by noise (still in range, so the parser
    waits for bytes that are really END), then END: the tail of a run a robot ends."""
    good = [encode_frame(i, i * 30_000, [float(i)], None, (2, 2)) for i in range(2)]
    hit = bytearray(encode_frame(2, 60_000, [2.0], None, (2, 2)))
    hit[3] ^= 0x04  # length + 1024: in FRAME's range, far past the end of the stream
    return b"".join(good) + bytes(hit) + encode(TYPE_END), 2


def test_a_damaged_length_cannot_hold_back_the_robots_end() -> None:
    stream, n_good = _stream_with_a_damaged_length_before_end()
    parser = PacketParser()
    got = list(parser.feed(stream))
    assert [t for t, _ in got] == [TYPE_FRAME] * n_good  # END waits behind the false length
    freed = parser.salvage()
    assert [t for t, _ in freed] == [TYPE_END]
    assert parser.stats.bad_length == 1 and not parser.buf
    # a packet that is merely incomplete (the rest on its way) is kept, not thrown away
    whole = encode_frame(3, 90_000, [3.0], np.zeros((2, 2), np.uint8), (2, 2))
    parser = PacketParser()
    assert not list(parser.feed(whole[:-3])) and parser.salvage() == []
    assert [decode_frame(p).index for _, p in parser.feed(whole[-3:])] == [3]
    assert parser.stats.bad_length == 0


def test_the_host_reads_a_robots_end_behind_a_damaged_length_on_a_pty() -> None:
    """The end-to-end pty test's rare 'did not come back within 30 s': noise in the last
    frame's length kept END in the host's buffer until the robot closed its port. On a real
    pseudo-terminal the host now ends its run with the robot's END and every intact frame."""
    import tty

    from capture.serial_link import SerialLink

    stream, n_good = _stream_with_a_damaged_length_before_end()
    master, slave = pty.openpty()
    tty.setraw(slave)
    try:
        link = SerialLink(os.ttyname(slave), reconnect_timeout_s=1.0)
        link.open()
        os.write(master, stream)  # and the robot says nothing more, its port left open
        frames, deadline = [], time.monotonic() + 60  # a loaded machine may deliver late
        for ptype, obj in link.packets():
            if ptype == TYPE_FRAME:
                frames.append(obj.index)
            assert time.monotonic() < deadline, "the host never read END"
        assert link.ended and frames == list(range(n_good))
        assert link.parser.stats.bad_length == 1
        link.close()
    finally:
        os.close(master)
        os.close(slave)


def test_packets_read_together_survive_a_caller_that_stops_after_each() -> None:
    """CI's 'did not come back within 30 s' after a clean run: a loaded host read the last
    frames and END in one chunk, its capture ended the batch on the first of them, and the
    rest went with the abandoned generator. On a real pty, a caller that takes one packet per
    call to ``packets()`` (as a capture's batch does when time is up) gets every frame and END."""
    import tty

    from capture.serial_link import SerialLink

    n = 5
    stream = b"".join(encode_frame(i, i * 30_000, [float(i)], None, (2, 2)) for i in range(n))
    master, slave = pty.openpty()
    tty.setraw(slave)
    try:
        link = SerialLink(os.ttyname(slave), reconnect_timeout_s=1.0)
        link.open()
        os.write(master, stream + encode(TYPE_END))  # one write: read in one chunk
        frames, deadline = [], time.monotonic() + 60  # a loaded machine may deliver late
        while not link.ended:
            for ptype, obj in link.packets():
                if ptype == TYPE_FRAME:
                    frames.append(obj.index)
                    break  # the batch is full: the caller stops here
                assert time.monotonic() < deadline, f"the host never read END (frames {frames})"
        assert frames == list(range(n))
        link.close()
    finally:
        os.close(master)
        os.close(slave)
