"""The robot handshake on a real pty: the host sends its model (PARAMS) with START, the robot
announces what it runs and its camera (ANNOUNCE); the host refuses a robot running another model
before writing anything, records a silent one as unverified, and records the robot's camera."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pty
import re
import subprocess
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from analysis.recordings.loading import load_recording
from analysis.recordings.reader import Recording
from analysis.recordings.recompute import recompute
from avdm.registry import make_model
from capture.robot_capture import (
    ColiasRobotDevice,
    RobotCaptureConfig,
    RobotSettings,
    record_robot,
)
from capture.serial_protocol import (
    TYPE_ANNOUNCE,
    TYPE_END,
    TYPE_PARAMS,
    TYPE_START,
    Announcement,
    PacketParser,
    decode_announce,
    encode,
    encode_announce,
    encode_frame,
)
from capture.tracker import save_calibration
from tests.helpers import assert_one_line_error, run_cli, start_emulator

AVDM_OUTPUTS = tuple((o.name, o.unit) for o in make_model("avdm").outputs)


def test_announce_round_trip_and_malformed_payloads() -> None:
    a = Announcement(
        "lgmd-plus:t_sr=80", (("spike_rate_hz", "1/s"), ("ffi", "")), 20.0, 80, 60, 0.75, 30
    )
    ((ptype, payload),) = list(PacketParser().feed(encode_announce(a)))
    assert ptype == TYPE_ANNOUNCE and decode_announce(payload) == a
    assert a.model_context() == {
        "fps": 20.0,
        "deg_per_px": 0.75,
        "texture_row": 30,
        "width_px": 80,
        "height_px": 60,
    }
    for bad in (payload[:-1], payload + b"\0", b"\x02" + payload[1:], payload[:10]):
        with pytest.raises(ValueError):
            decode_announce(bad)


def overhead_frames(folder: Path, n: int = 3) -> Path:
    """A few blank overhead frames and a saved calibration beside them: the tracker finds no
    robot (poses are not tested here)."""
    folder.mkdir()
    for k in range(n):
        cv2.imwrite(str(folder / f"{k:05d}.png"), np.full((120, 200), 128, np.uint8))
    save_calibration(np.eye(3), folder / "calibration.json")
    return folder / "%05d.png"


def camera_section(fps: float, width_px: int, height_px: int, announced: bool) -> dict:
    """A recording's ``camera`` property section as expected: every camera here has the
    robot's pitch (70/99 deg a px), so its field of view is 70 deg whatever its width (rel
    1e-12: the pitch times the width in floating point)."""
    return {
        "fps": fps,
        "width_px": width_px,
        "height_px": height_px,
        "hfov_deg": pytest.approx(70.0, rel=1e-12),
        "announced": announced,
    }


def emulator(link: Path, report: Path, *extra: str) -> subprocess.Popen:
    """The emulator waiting up to 60 s for the host's START."""
    return start_emulator(link, report, "--wait", "60", *extra)


def capture(link: Path | str, camera: Path, out: Path, model: str) -> subprocess.CompletedProcess:
    return run_cli(
        "capture",
        "robot",
        "--port",
        str(link),
        "--camera",
        str(camera),
        "--camera-fps",
        "50",
        "--calibration",
        str(camera.parent / "calibration.json"),
        "--model",
        model,
        "--out",
        str(out),
        "--quiet",
        timeout=120,
    )


def test_a_robot_running_another_model_is_refused_before_any_file(tmp_path: Path) -> None:
    link, report = tmp_path / "robot", tmp_path / "report.json"
    emu = emulator(link, report, "--model", "lgmd-plus", "--minutes", "0.05", "--fast")
    out = tmp_path / "rec.rrd"
    proc = capture(link, overhead_frames(tmp_path / "overhead"), out, "avdm")
    emu.communicate(timeout=60)  # the host's STOP ends the emulated run
    assert_one_line_error(proc, "the robot runs lgmd-plus", "--model avdm")
    assert not list(tmp_path.glob("*.rrd")) and not list(tmp_path.glob(".*lock"))
    assert json.loads(report.read_text())["model"] == "lgmd-plus"


def await_start(master: int, seen: list[tuple[int, bytes]], deadline: float) -> bool:
    """Read what the host sends on ``master`` (each packet's type and payload into ``seen``)
    until its START, as a firmware does; whether it came before ``deadline``."""
    parser = PacketParser()
    while time.monotonic() < deadline:
        try:
            data = os.read(master, 4096)
        except BlockingIOError:
            time.sleep(0.01)
            continue
        for ptype, payload in parser.feed(data):
            seen.append((ptype, payload))
            if ptype == TYPE_START:
                return True
    return False


def fake_robot(master: int, announcement: Announcement, seen: list[tuple[int, bytes]]) -> None:
    """Answer the host's START with ``announcement`` (what a firmware would send)."""
    if await_start(master, seen, time.monotonic() + 20):
        os.write(master, encode_announce(announcement))


@pytest.mark.parametrize(
    ("outputs", "needle"),
    [
        (AVDM_OUTPUTS[:-1], f"sends {len(AVDM_OUTPUTS) - 1} outputs"),
        ((*AVDM_OUTPUTS[:-1], ("speed", "1")), "speed [1]"),
        # an output named like one of vdc's per-frame columns: never a model's (a plug-in with
        # one is refused at the door, avdm/plugins.py), so never what the host builds either
        ((*AVDM_OUTPUTS[:-1], ("t_s", "s")), "t_s [s]"),
        (AVDM_OUTPUTS, None),  # the control: the model's own outputs are accepted
    ],
)
def test_outputs_that_differ_from_the_model_are_refused(tmp_path: Path, outputs, needle) -> None:
    master, slave = pty.openpty()
    os.set_blocking(master, False)
    seen: list[tuple[int, bytes]] = []
    robot = threading.Thread(
        target=fake_robot,
        args=(master, Announcement("avdm", outputs, 33.0, 99, 72, 70 / 99, 36), seen),
    )
    robot.start()
    cfg = RobotCaptureConfig(
        port=os.ttyname(slave), camera=str(overhead_frames(tmp_path / "o")), model="avdm"
    )
    device = ColiasRobotDevice(cfg)
    try:
        if needle is None:
            device.connect()
            assert device.announced is not None and device.announced.outputs == AVDM_OUTPUTS
            device.disconnect()
        else:
            with pytest.raises(ValueError, match=re.escape(needle)) as err:
                device.connect()
            assert "\n" not in str(err.value)
    finally:
        robot.join(timeout=30)
        os.close(master)
        os.close(slave)
    # the host asked for its model before START
    assert [t for t, _ in seen[:2]] == [TYPE_PARAMS, TYPE_START] and seen[0][1] == b"avdm"


def test_a_silent_robot_is_recorded_as_unverified(tmp_path: Path) -> None:
    link, report, out = tmp_path / "robot", tmp_path / "report.json", tmp_path / "rec.rrd"
    emu = emulator(link, report, "--silent", "--minutes", "0.05", "--fast")
    proc = capture(link, overhead_frames(tmp_path / "overhead"), out, "avdm")
    emu.communicate(timeout=60)
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if "announce" in ln or "verified" in ln]
    assert len(lines) == 1 and "unverified" in lines[0], lines
    assert "did not announce its model (it sent frames without announcing" in lines[0]
    props = Recording(out).properties()
    assert props["model"]["verified"] is False and props["model"]["name"] == "avdm"
    # the host's defaults, said to be so: the robot's camera is not known
    assert props["model_context"]["width_px"] == 99 and props["model_context"]["fps"] == 33.0
    assert props["camera"]["announced"] is False
    assert "UNVERIFIED" in (Recording(out).description() or "")
    assert len(Recording(out).read_frames().frame) == json.loads(report.read_text())["frames"]


def test_the_robots_announced_camera_and_asked_model_are_recorded(tmp_path: Path) -> None:
    link, report, out = tmp_path / "robot", tmp_path / "report.json", tmp_path / "rec.rrd"
    # a camera unlike the host's defaults (99 x 72 px, 33 Hz, 70 deg): the robot's must win
    emu = emulator(
        link,
        report,
        "--minutes",
        "0.05",
        "--fast",
        "--fps",
        "20",
        "--width-px",
        "80",
        "--height-px",
        "60",
        "--hfov-deg",
        "60",
    )
    proc = capture(link, overhead_frames(tmp_path / "overhead"), out, "avdm:beta=0.5")
    emu.communicate(timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "warning" not in proc.stderr and "unverified" not in proc.stderr  # no notice
    assert json.loads(report.read_text())["model"] == "avdm:beta=0.5"  # PARAMS reached it
    rec = Recording(out)
    props = rec.properties()
    assert props["model"]["name"] == "avdm:beta=0.5" and props["model"]["verified"] is True
    assert props["model_params"]["beta"] == 0.5
    assert props["model_context"] == {
        "fps": 20.0,
        "deg_per_px": 0.75,
        "texture_row": 30,
        "width_px": 80,
        "height_px": 60,
    }
    assert props["model_params"]["texture_row"] == 30 and props["model_params"]["fps"] == 20.0
    assert (props["camera"]["width_px"], props["camera"]["height_px"]) == (80, 60)
    assert props["camera"]["hfov_deg"] == pytest.approx(60.0, rel=1e-12)  # 0.75 x 80
    frames = rec.read_frames()
    assert frames.images.shape[1:] == (60, 80)
    text = rec.description() or ""
    for needle in (
        "`avdm:beta=0.5` (run on board; the robot announced it)",
        "80 x 60 px at 20 Hz, 0.75 deg/px (60 deg wide), texture row 30",
    ):
        assert needle in text, text
    # recomputed from the recorded context, the model gives the floats the robot sent (as f32)
    loaded = load_recording(out)
    again = recompute(loaded, ["avdm:beta=0.5"])["avdm:beta=0.5"]
    logged = loaded.logged["avdm:beta=0.5"]
    assert again.height == logged.height == len(frames.frame)
    # the link carries f32: equal to float32 rounding (relative 2^-24 ~ 6e-8)
    np.testing.assert_allclose(
        logged["omega_dps"].to_numpy(), again["omega_dps"].to_numpy(), rtol=1e-6, atol=1e-9
    )


def test_a_robot_that_says_nothing_is_given_up_on_after_the_timeout(tmp_path: Path) -> None:
    master, slave = pty.openpty()
    cfg = RobotCaptureConfig(
        port=os.ttyname(slave),
        camera=str(overhead_frames(tmp_path / "o")),
        announce_timeout_s=0.3,
        wall_port="/dev/ttyWALL",
    )
    device = ColiasRobotDevice(cfg)
    try:
        device.connect()  # nobody answers: no refusal, no announcement
        assert device.announced is None and "no answer within 0.3 s" in device.link.no_announce
        assert device.model_context["width_px"] == 99  # the host's defaults, marked as such
        # and so it describes itself: the defaults, not announced; the wall controller named
        props = device.properties()
        assert props["camera"] == camera_section(33.0, 99, 72, announced=False)
        assert props["link"]["announce"] == "none (older firmware?)"
        assert "(/dev/ttyWALL wall controller)" in device.description()
        device.disconnect()
    finally:
        os.close(master)
        os.close(slave)


# -- a robot held to what it announced ------------------------------------------------------
def scripted_robot(master: int, packets: list[bytes]) -> None:
    """Answer the host's START with ``packets`` (an ANNOUNCE, FRAMEs, ...) and END, as a
    firmware would; the writes wait while the host has not read enough (a pty holds a few kB)."""
    deadline = time.monotonic() + 30
    await_start(master, [], deadline)
    blob = b"".join(packets) + encode(TYPE_END)  # the run is over: a host never waits on
    while blob and time.monotonic() < deadline:
        try:
            blob = blob[os.write(master, blob) :]
        except (BlockingIOError, OSError):
            time.sleep(0.01)


SMALL = Announcement("avdm", AVDM_OUTPUTS, 33.0, 20, 16, 70 / 20, 8)  # a small camera: fast


def frames_of(a: Announcement, first: int, n: int, shape=None, outputs=None) -> list[bytes]:
    """``n`` FRAME packets from index ``first`` on ``a``'s camera (or ``shape`` (H, W)), each
    with ``a``'s number of outputs (or ``outputs``)."""
    h, w = shape or (a.height_px, a.width_px)
    rng = np.random.default_rng(first)
    values = [0.5] * len(a.outputs) if outputs is None else outputs
    return [
        encode_frame(
            k, round(k * 1e6 / a.fps), values, rng.integers(0, 255, (h, w), np.uint8), (h, w)
        )
        for k in range(first, first + n)
    ]


def with_robot(tmp_path: Path, packets: list[bytes], run, **cfg):
    """``run(config)`` against a scripted robot on a real pty; what ``run`` returns."""
    master, slave = pty.openpty()
    os.set_blocking(master, False)
    robot = threading.Thread(target=scripted_robot, args=(master, packets), daemon=True)
    robot.start()
    camera = overhead_frames(tmp_path / "o")
    config = dict(port=os.ttyname(slave), camera=str(camera), model="avdm", **cfg)
    try:
        return run(config, camera)
    finally:
        robot.join(timeout=30)
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize(
    ("announce", "packets", "needle"),
    [
        # announced 99 x 72, sends 80 x 60 (the fault found: recorded as verified at 99 x 72)
        (
            Announcement("avdm", AVDM_OUTPUTS, 33.0, 99, 72, 70 / 99, 36),
            "shape",
            "frame 0 is 80x60 px, the camera 99x72 px",
        ),
        (SMALL, "outputs", f"frame 0 carries 3 outputs, avdm has {len(AVDM_OUTPUTS)}"),
        (SMALL, "infinite", "frame 0 has infinite omega_dps"),
        (dataclasses.replace(SMALL, width_px=0), "", "a 0x16 px camera"),
        (dataclasses.replace(SMALL, texture_row=16), "", "texture row 16, outside its 16 px"),
        (dataclasses.replace(SMALL, fps=math.inf), "", "a camera rate of inf Hz"),
        (dataclasses.replace(SMALL, fps=0.0), "", "a camera rate of 0.0 Hz"),
        (dataclasses.replace(SMALL, deg_per_px=math.nan), "", "nan deg/px"),
    ],
)
def test_a_robot_that_breaks_its_announcement_at_the_start_is_refused(
    tmp_path: Path, announce: Announcement, packets: str, needle: str
) -> None:
    first = {
        "shape": dict(shape=(60, 80)),
        "outputs": dict(outputs=[0.5, 0.5, 0.5]),
        "infinite": dict(outputs=[math.inf] + [0.5] * 6),
        "": {},
    }[packets]
    first = frames_of(announce if packets else SMALL, 0, 3, **first)
    out = tmp_path / "rec.rrd"

    def run(config, _camera):
        settings = RobotSettings(
            port=config["port"],
            camera=config["camera"],
            calibration=str(_camera.parent / "calibration.json"),
        )
        with pytest.raises(ValueError) as err:
            record_robot(settings, out, warn=lambda _: None)
        return str(err.value)

    message = with_robot(tmp_path, [encode_announce(announce), *first], run)
    assert needle in message and "\n" not in message, message
    assert not list(tmp_path.glob("*.rrd")) and not list(tmp_path.glob(".*lock"))


def test_a_robot_that_announces_the_same_parameters_otherwise_spelt_is_accepted(
    tmp_path: Path,
) -> None:
    a = dataclasses.replace(SMALL, model="avdm:beta=0.25")  # avdm's own beta
    assert make_model("avdm").params.beta == 0.25  # (what makes the two the same model)

    def run(config, _camera):
        device = ColiasRobotDevice(RobotCaptureConfig(**config))
        device.connect()
        device.disconnect()
        return device

    device = with_robot(tmp_path, [encode_announce(a), *frames_of(a, 0, 2)], run)
    assert device.announced == a and device.model_name == "avdm"
    # another beta is another model, whatever the spelling
    b = dataclasses.replace(SMALL, model="avdm:beta=0.5")
    (tmp_path / "b").mkdir()
    with pytest.raises(ValueError, match=re.escape("the robot runs avdm:beta=0.5")):
        with_robot(tmp_path / "b", [encode_announce(b)], run)


@pytest.mark.parametrize("change", ["frame size", "outputs", "announcement"])
def test_a_robot_that_changes_mid_run_ends_the_capture_cleanly(tmp_path: Path, change) -> None:
    other = dataclasses.replace(SMALL, width_px=24, height_px=18, texture_row=9)
    tail = {
        "frame size": frames_of(SMALL, 11, 3, shape=(18, 24)),
        "outputs": frames_of(SMALL, 11, 3, outputs=[0.5] * 3),
        "announcement": [encode_announce(other), *frames_of(other, 11, 3)],
    }[change]
    packets = [encode_announce(SMALL), *frames_of(SMALL, 0, 11), *tail]
    out = tmp_path / "rec.rrd"

    def run(config, camera):
        return capture(config["port"], camera, out, "avdm")

    proc = with_robot(tmp_path, packets, run)
    assert proc.returncode == 1, proc.stderr
    # one line says why it ended (beside the usual "recording ... -> ..." line)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "recording robot-" not in ln]
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "error:" in lines[0] and "the 11 frames before it" in lines[0], lines[0]
    why = {
        "frame size": "frame 11 is 24x18 px, the camera 20x16 px",
        "outputs": "frame 11 carries 3 outputs, avdm has 7",
        "announcement": "mid-run the robot announces avdm on a 24x18 camera",
    }[change]
    assert why in lines[0], lines[0]
    rec = Recording(out)
    frames = rec.read_frames()
    assert frames.frame.tolist() == list(range(11))  # every frame before the change, kept
    assert frames.images.shape == (11, 16, 20)
    events = rec.events()
    texts = [t for k, t in zip(events["kind"], events["text"], strict=True) if k == "link_error"]
    assert len(texts) == 1 and "capture ends here" in texts[0], texts
    assert rec.properties()["run_end"]["stop_reason"] == "link error"
    assert not list(tmp_path.glob("*.partial.rrd")) and not list(tmp_path.glob(".*lock"))


def test_the_robot_describes_itself_in_its_recording(tmp_path: Path) -> None:
    """What the user sees in the viewer: the device's properties and description, from the
    settings it was given and the camera the robot announced."""
    out = tmp_path / "rec.rrd"

    def run(config, camera):
        settings = RobotSettings(
            port=config["port"],
            camera=config["camera"],
            tf_hz=2.0,
            calibration=str(camera.parent / "calibration.json"),
        )
        record_robot(settings, out, warn=lambda _: None)
        return config["port"], config["camera"]

    port, camera = with_robot(tmp_path, [encode_announce(SMALL), *frames_of(SMALL, 0, 5)], run)
    rec = Recording(out)
    props = rec.properties()
    assert props["run"] == {
        "recording_id": rec.recording_id,
        "source": "robot",
        "port": port,
        "baud": 3_000_000,
        "camera": camera,
        "behaviour": "robot",
    }
    assert props["camera"] == camera_section(33.0, 20, 16, announced=True)
    # the schedule: 2 Hz until the settings' 48 h, in the form the schedule flag takes
    assert props["wall"] == {"scene": "grating", "period_m": 0.1, "tf_schedule_text": "2:172800s"}
    assert props["link"]["announce"] == "received" and props["arena"]["length_m"] > 0
    text = rec.description() or ""
    for needle in (
        f"a Colias-IV robot on {port} (no wall controller)",
        f"overhead camera {camera}; wall grating, TF schedule 2:172800s",
    ):
        assert needle in text, text
