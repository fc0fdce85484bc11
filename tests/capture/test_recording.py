"""``vdc-capture sim`` recordings: the contract's entities, timelines, properties; bit-exact
frames; online outputs reproducible offline; clean stops on signals; bad input."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from analysis.recordings.reader import Recording
from avdm import make_model
from capture.config import SimConfig, WallConfig, parse_schedule
from capture.sim_robot import SimulatedRobot
from tests.helpers import assert_one_line_error, run_cli, spawn, start_long_capture, wait_until
from tests.in_process import run_in_process

CONTRACT_ENTITIES = {
    "/arena/walls",
    "/arena/ring",
    "/arena/wall/tf_hz",
    "/robot/pose",
    "/robot",
    "/robot/camera/image",
    "/model/avdm/omega_dps",
    "/model/avdm/lambda_px",
    "/model/avdm/motion",
    "/model/avdm/contrast",
    "/events/ring_turn",
    "/overhead/image",
}


def record_short_run(out: Path) -> str:
    """The short run through the command line (30 s, TF 0 then 3 Hz, seed 3, the overhead
    camera) into ``out``; its stdout."""
    proc = run_in_process(
        "capture",
        "sim",
        "--tf-schedule",
        "0:10s,3:20s",
        "--seed",
        "3",
        "--overhead",
        "--out",
        str(out),
        "--quiet",
    )
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


@pytest.fixture(scope="module")
def short_recording(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("rec") / "short.rrd"
    stdout = record_short_run(out)
    assert "wrote" in stdout and "990 frames" in stdout
    return out


def test_recording_holds_the_contract(short_recording: Path) -> None:
    reader = rr.chunk.RrdReader(str(short_recording))
    (entry,) = reader.recordings()
    assert entry.application_id == "vdc"
    assert entry.recording_id.startswith("grating-tf0-3-s3-")
    entities, timelines = set(), set()
    for ch in reader.store().stream():
        entities.add(ch.entity_path)
        timelines.update(ch.timeline_names)
    assert CONTRACT_ENTITIES <= entities, CONTRACT_ENTITIES - entities
    assert {"frame", "time"} <= timelines
    assert "log_time" not in timelines  # columns only: deterministic content
    assert len(reader.blueprints()) >= 1  # the default blueprint travels with it


def test_properties_record_every_config_value(short_recording: Path) -> None:
    props = Recording(short_recording).properties()
    cfg = SimConfig()
    for section in (
        "arena",
        "wall",
        "robot",
        "camera",
        "overhead",
        "run",
        "model",
        "model_params",
        "run_end",
    ):
        assert section in props, section
    assert set(props["arena"]) >= set(cfg.to_sections()["arena"])
    assert set(props["robot"]) >= set(cfg.to_sections()["robot"])
    assert props["wall"]["tf_schedule_text"] == "0:10s,3:20s"
    assert props["run"]["seed"] == 3 and props["run"]["vdc_version"]
    assert props["model"]["name"] == "avdm"
    assert props["model_params"]["fps"] == 33.0 and props["model_params"]["a"] > 0
    assert props["run_end"]["complete"] is True and props["run_end"]["frames"] == 990


def test_frames_come_back_bit_exact_and_outputs_recompute_exactly(short_recording) -> None:
    rec = Recording(short_recording)
    frames = rec.read_frames()
    assert np.array_equal(frames.frame, np.arange(990))
    cfg = SimConfig(
        wall=WallConfig(tf_schedule=parse_schedule("0:10s,3:20s")), seed=3, duration_s=30.0
    )
    with SimulatedRobot(cfg) as dev:
        rendered = dev.read().images
    assert np.array_equal(frames.images, rendered)
    model = make_model("avdm", **cfg.camera.model_context())  # texture row = horizon
    offline = model.run(frames.images)
    logged = rec.model_outputs("avdm", ["omega_dps", "lambda_px", "motion", "contrast"])
    for key in ("omega_dps", "lambda_px", "motion", "contrast"):
        assert np.array_equal(offline[key], logged[key]), key
    f, t, tf = rec.wall_tf()
    assert (tf[f < 330, 0] == 0).all() and (tf[f >= 330, 0] == 3).all()
    np.testing.assert_allclose(t, f / 33.0, atol=1e-9)
    f, _, poses = rec.poses()
    assert poses.shape == (990, 3)
    ev = rec.events()
    assert ev.height > 0 and set(ev["kind"]) == {"ring_turn"}
    hx, hy = 0.7, 0.4
    assert (np.minimum(hx - ev["x_m"].abs(), hy - ev["y_m"].abs()) < 0.13).all()


def test_same_seed_same_recording_content(short_recording: Path, tmp_path: Path) -> None:
    again = tmp_path / "again.rrd"
    record_short_run(again)
    a, b = Recording(short_recording), Recording(again)
    assert a.recording_id == b.recording_id
    assert np.array_equal(a.read_frames().images, b.read_frames().images)
    assert np.array_equal(a.poses()[2], b.poses()[2])


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_stops_cleanly_with_a_valid_recording(tmp_path: Path, sig, code) -> None:
    out = tmp_path / "cut.rrd"
    proc = start_long_capture(out)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == code, stderr
    assert f"stopped by signal {sig.name}" in stdout
    assert "valid recording" in stdout
    rec = Recording(out)
    assert rec.notice is None  # footer written: the lazy reader opens it
    props = rec.properties()
    assert props["run_end"]["complete"] is False
    assert props["run_end"]["stop_reason"] == f"signal {sig.name}"
    frames = rec.read_frames()
    n = props["run_end"]["frames"]
    assert 0 < n < 60 * 60 * 33
    assert np.array_equal(frames.frame, np.arange(n))  # every frame so far, none missing
    assert len(rec.poses()[0]) == n


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["--tf-schedule", "3:30x"], ["not TF:DURATION"]),
        (["--tf-schedule", "3:30m", "--tf-hz", "2"], ["not allowed with"]),
        (["--minutes", "-1"], ["positive number"]),
        (["--minutes", "abc"], ["expected a number"]),
        (["--tf-hz", "500"], ["--tf-hz", "Nyquist", "16.5 Hz"]),
        (["--scene", "stars"], ["invalid choice"]),
        (["--model", "nope"], ["unknown model 'nope'"]),
        (["--model", "avdm:beta=x"], ["expected a number"]),
        (["--scene", "natural", "--image", "/nonexistent.png"], ["does not exist"]),
        (["--image", "x.png"], ["--scene natural"]),
        (["--contrast", "3"], ["--contrast", "in (0, 1]"]),
        (["--seed", "-2"], ["non-negative integer"]),
        (["--period-m", "0"], ["positive number"]),
    ],
)
def test_bad_input_gives_one_line_exit_2_and_no_file(tmp_path: Path, args, needles) -> None:
    out = tmp_path / "bad.rrd"
    # in this process (tests.in_process): the parse and checks of the command line only
    proc = run_in_process("capture", "sim", "--minutes", "0.05", *args, "--out", str(out))
    if "--minutes" in args:  # the test's own --minutes comes first; theirs wins
        proc = run_in_process("capture", "sim", *args, "--out", str(out))
    assert_one_line_error(proc, *needles)
    assert not out.exists()


def natural_scene(image: Path) -> tuple[str, ...]:
    """The command line of a simulated run on a natural wall made of ``image``."""
    return ("capture", "sim", "--scene", "natural", "--image", str(image))


def test_unreadable_image_unwritable_output_and_existing_file(tmp_path: Path) -> None:
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not an image at all")
    out = tmp_path / "x.rrd"
    proc = run_in_process(*natural_scene(junk), "--minutes", "0.05", "--out", str(out))
    assert_one_line_error(proc, "not a readable image")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    proc = run_in_process("capture", "sim", "--minutes", "0.05", "--out", str(blocker / "x.rrd"))
    assert_one_line_error(proc, "cannot create the folder")
    proc = run_in_process("capture", "sim", "--minutes", "0.05", "--out", str(tmp_path / "x.txt"))
    assert_one_line_error(proc, "must end in .rrd")
    out.write_bytes(b"precious")
    proc = run_in_process("capture", "sim", "--minutes", "0.05", "--out", str(out))
    assert_one_line_error(proc, "already exists", "--force")
    assert out.read_bytes() == b"precious"
    proc = run_in_process(
        "capture", "sim", "--minutes", "0.05", "--out", str(out), "--force", "--quiet"
    )
    assert proc.returncode == 0, proc.stderr


def test_natural_scene_from_an_image_file(tmp_path: Path) -> None:
    import cv2

    img = (np.random.default_rng(0).random((60, 400)) * 255).astype(np.uint8)
    path = tmp_path / "scene.png"
    cv2.imwrite(str(path), img)
    out = tmp_path / "nat.rrd"
    proc = run_in_process(
        *natural_scene(path), "--tf-hz", "3", "--minutes", "0.1", "--out", str(out), "--quiet"
    )
    assert proc.returncode == 0, proc.stderr
    rec = Recording(out)
    assert rec.properties()["wall"]["image_path"] == str(path)
    assert rec.read_frames().images.shape == (198, 72, 99)


def test_connect_tees_to_a_live_viewer_while_writing_the_file(tmp_path: Path) -> None:
    """A real Rerun gRPC receiver (the viewer binary in --save mode) gets the same frames."""
    import shutil
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    received = tmp_path / "received.rrd"
    exe = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")
    receiver = spawn(
        [exe, "--bind", "127.0.0.1", "--port", str(port), "--save", str(received)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:

        def listening() -> bool:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                return True
            except OSError:
                return receiver.poll() is not None  # it ended: stop waiting, the assert says

        assert wait_until(listening, 120) and receiver.poll() is None, "the receiver never listened"
        out = tmp_path / "teed.rrd"
        proc = run_cli(
            "capture",
            "sim",
            "--minutes",
            "0.1",
            "--out",
            str(out),
            "--quiet",
            "--connect",
            f"rerun+http://127.0.0.1:{port}/proxy",
        )
        assert proc.returncode == 0, proc.stderr
        deadline = time.time() + 30
        frames = None
        while time.time() < deadline:
            try:
                frames = Recording(received).read_frames()
                if len(frames.frame) == 198:
                    break
            except Exception:
                pass
            time.sleep(0.5)
        assert frames is not None and len(frames.frame) == 198
        assert np.array_equal(frames.images, Recording(out).read_frames().images)
    finally:  # the autouse fixture also ends it if anything above raised first
        receiver.terminate()
        receiver.wait(timeout=10)
