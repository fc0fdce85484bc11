"""``vdc-analyse dataset`` against its own metadata: a LeRobot dataset's ``info.json`` and
episode index are claims, held against the video's own frame times and the data's timestamps.
Each test edits a tiny dataset written by ``analysis.dataset.synthetic`` one way (a wrong or
malformed field, an episode listed twice, a window or timestamps that are not times or run
backwards) and checks that the checker says so, naming the file and the field, instead of
measuring silently wrong or failing with a traceback."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from analysis.dataset import DatasetSettings, dataset
from analysis.dataset.layout import open_dataset
from analysis.dataset.rates import agreed_rate
from analysis.dataset.synthetic import Faults, write_dataset
from tests.helpers import ROOT, assert_one_line_error, flags, write_h264_dataset
from tests.in_process import run_in_process
from vdc.errors import UserError

CAM = "observation.images.front"
FPS = 30.0
DROPPED = (10, 5)  # episode 2 loses frames 10-14 of its 30
INDEX = "meta/episodes/chunk-000/file-000.parquet"
DATA = "data/chunk-000/file-000.parquet"


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    d = tmp_path_factory.mktemp("meta")
    small = {"codec": "libx264", "shape": (48, 64), "seconds": (1.0, 1.0), "episodes": 3}
    write_dataset(d / "v3", version="v3.0", faults=Faults(dropped={2: DROPPED}), **small)
    write_dataset(d / "v21", version="v2.1", faults=Faults(), **small)
    return d


def _copy(made, name: str, to: str):
    dst = made / to
    shutil.copytree(made / name, dst)
    return dst


def _edit_info(root, **fields) -> None:
    path = root / "meta" / "info.json"
    info = json.loads(path.read_text())
    # json.dumps writes NaN and Infinity as the bare tokens a JSON writer in Python leaves
    path.write_text(json.dumps(info | fields))


def _edit_table(path, edit) -> None:
    schema = pq.read_schema(path)
    cols = pq.read_table(path).to_pydict()
    edit(cols)
    keep = pa.schema([f for f in schema if f.name in cols])
    pq.write_table(pa.table(cols, schema=keep if set(keep.names) == set(cols) else None), path)


def _run(root, out, **settings):
    opts = {"jobs": 1, "page": False, "recordings": False} | settings
    return dataset(root, DatasetSettings(**opts), out)


def _rows(res) -> dict[int, dict]:
    return {r["episode_index"]: r for r in res.episodes.iter_rows(named=True)}


# -- the rate ----------------------------------------------------------------------------------
@pytest.mark.parametrize("stated", [15, 60])
def test_a_wrong_fps_is_a_dataset_problem_and_the_rate_two_agree_on_is_used(made, stated) -> None:
    """info.json's fps 15 (or 60) for a 30-fps video whose data's timestamps are 30 fps: the
    video and the data agree, so the episodes are measured at 30 fps (episode 2's 5 lost
    frames counted 5, not 2 or 1,265 invented over the clean ones), and the disagreement is a
    problem of the dataset naming the field and each rate."""
    root = _copy(made, "v3", f"fps{stated}")
    _edit_info(root, fps=stated)
    res = _run(root, made / f"o_fps{stated}", page=True)
    rows = _rows(res)
    assert rows[2]["dropped"] == DROPPED[1] and rows[2]["flags"] == "dropped"
    for e in (0, 1):
        assert rows[e]["dropped"] == 0 and rows[e]["flags"] == "", rows[e]
    assert all(r["fps"] == FPS for r in rows.values())
    assert res.exit_status == 2
    (line,) = res.dataset_problems
    for needle in (
        "meta/info.json",
        f"fps {stated}",
        "video's frames 30 fps",
        "timestamp 30 fps",
        "measured at 30 fps",
    ):
        assert needle in line, (needle, line)
    assert any("dataset problem" in ln and f"fps {stated}" in ln for ln in res.report())
    problems = pl.read_parquet(res.files.problems)
    assert (
        problems.filter(pl.col("episode_index").is_null())["message"]
        .str.contains(f"fps {stated}")
        .all()
    )
    assert f"info.json&#x27;s fps {stated}" in res.files.dataset.read_text()


def test_data_timestamps_at_another_rate_are_outvoted_and_named(made) -> None:
    """The data's timestamps spaced as 15 fps under a stated and encoded 30: measured at 30
    (the two that agree), the timestamps' rate named as the odd one."""
    root = _copy(made, "v3", "ts15")
    _edit_table(root / DATA, lambda c: c.update(timestamp=[2 * t for t in c["timestamp"]]))
    ds = open_dataset(root)
    assert ds.rate(CAM) == FPS
    (p,) = ds.problems
    assert p.episode is None and "timestamp 15 fps" in p.message and "fps 30" in p.message


def test_a_cameras_own_video_fps_is_held_against_its_video(made) -> None:
    """A camera's own ``video.fps`` (LeRobot's per-camera info) of 15 on a 30-fps video: the
    camera may record at a rate of its own, but this one's video says 30: measured at 30, the
    disagreement named; the same 15 borne out by a 15-fps video is no problem
    (test_dataset_cameras.py)."""
    root = _copy(made, "v3", "own15")
    info = json.loads((root / "meta" / "info.json").read_text())
    info["features"][CAM]["info"]["video.fps"] = 15
    _edit_info(root, features=info["features"])
    ds = open_dataset(root)
    assert ds.rate(CAM) == FPS == ds.data_rate(CAM)
    (p,) = ds.problems
    assert f"{CAM} video.fps 15" in p.message and "video's frames 30 fps" in p.message


def test_the_rate_followed_is_the_one_the_evidence_agrees_on() -> None:
    stated, video, data = ("stated", 30.0), ("video", 29.97), ("data", 15.0)
    assert agreed_rate([stated, video, data]) == (30.0, False)  # 30 and 29.97 agree
    assert agreed_rate([("stated", 60.0), video, ("data", 29.97)]) == (29.97, False)
    assert agreed_rate([("stated", 60.0), ("video", 30.0), data]) == (30.0, False)  # none agree
    assert agreed_rate([("stated", 25.0), ("video", None), ("data", 30.0)]) == (30.0, False)
    assert agreed_rate([stated, ("video", 30.0), ("data", 30.0)]) == (30.0, True)


@pytest.mark.parametrize("fps", [float("nan"), float("inf"), True, 0, -30, "30", None], ids=repr)
def test_a_rate_that_is_not_a_rate_is_refused_in_one_line(made, fps) -> None:
    root = _copy(made, "v3", f"bad_fps_{fps!r}")
    _edit_info(root, fps=fps)
    with pytest.raises(UserError, match=r"meta/info\.json: fps .* is not a rate"):
        open_dataset(root)


def test_fps_infinity_on_the_command_line_is_one_line(made) -> None:
    root = _copy(made, "v3", "fps_inf")
    _edit_info(root, fps=float("inf"))
    proc = run_in_process("analysis", "dataset", str(root), "--out", str(made / "o_inf"))
    assert_one_line_error(proc, "meta/info.json", "fps Infinity", "not a rate")


# -- malformed metadata: one line naming the file and the field -------------------------------
@pytest.mark.parametrize(
    "version, fields, needles",
    [
        ("v3", {"features": "observation.images.front"}, ["info.json", "features is a str"]),
        (
            "v3",
            {"video_path": "videos/{camera}/file-{file_index:03d}.mp4"},
            ["info.json", "video_path", "{camera}"],
        ),
        (
            "v21",
            {"data_path": "data/{episode_index:06d}/{chunk}.parquet"},
            ["info.json", "data_path", "{chunk}"],
        ),
        ("v21", {"chunks_size": 0}, ["info.json", "chunks_size 0"]),
    ],
    ids=["features-a-string", "unknown-key-v3", "unknown-key-v2", "chunks-size-0"],
)
def test_a_malformed_info_json_is_one_line(made, version, fields, needles) -> None:
    root = _copy(made, version, "info_" + "_".join(fields))
    _edit_info(root, **fields)
    with pytest.raises(UserError) as err:
        open_dataset(root)
    for needle in needles:
        assert needle in str(err.value), (needle, str(err.value))


@pytest.mark.parametrize("column", ["length", "episode_index"])
def test_an_episode_index_without_a_column_is_one_line(made, column) -> None:
    root = _copy(made, "v3", f"no_{column}")
    _edit_table(root / INDEX, lambda c: c.pop(column))
    proc = run_in_process("analysis", "dataset", str(root), "--out", str(made / f"o_{column}"))
    assert_one_line_error(proc, "file-000.parquet", f"no column {column}")


def test_a_null_length_is_the_episodes_problem_and_the_others_are_listed(made) -> None:
    root = _copy(made, "v3", "null_length")
    _edit_table(root / INDEX, lambda c: c["length"].__setitem__(1, None))
    ds = open_dataset(root)
    assert ds.episodes == [0, 2]
    (p,) = ds.problems
    assert p.episode == 1 and p.file.endswith("file-000.parquet") and "length None" in p.message


def test_v2_lines_without_a_length_or_an_index_or_in_binary_are_each_a_problem(made) -> None:
    root = _copy(made, "v21", "v2_lines")
    path = root / "meta" / "episodes.jsonl"
    lines = path.read_bytes().splitlines()
    lines[1] = json.dumps({"episode_index": 1, "length": None}).encode()
    lines.append(json.dumps({"length": 30}).encode())
    lines.append(b"\xff\xfe\x00\x9c binary \x00")
    path.write_bytes(b"\n".join(lines) + b"\n")
    ds = open_dataset(root)
    assert ds.episodes == [0, 2] and ds.listed == [0, 1, 2]
    said = sorted(p.line() for p in ds.problems)
    assert len(said) == 3, said
    assert any("(episode 1)" in s and "line 2: length None" in s for s in said)
    assert any("line 4: episode_index None" in s for s in said)
    assert any("line 5 is not a JSON record" in s for s in said)
    assert all(s.startswith(str(path)) for s in said)


def test_an_index_with_no_readable_episode_is_one_line(made) -> None:
    root = _copy(made, "v21", "v2_binary")
    (root / "meta" / "episodes.jsonl").write_bytes(b"\x00\xff\xfe binary\n\x89PNG\r\n")
    proc = run_in_process("analysis", "dataset", str(root), "--out", str(made / "o_bin"))
    assert_one_line_error(proc, "episodes.jsonl", "line 1", "no episode can be read")


# -- the episode index: duplicates and windows ------------------------------------------------
def test_an_episode_listed_twice_is_said_and_measured_once_or_not_at_all(made) -> None:
    root = _copy(made, "v3", "twice")

    def again(cols, change: bool) -> None:
        for values in cols.values():
            values.append(values[1])  # episode 1's row again, at the end
        if change:
            cols["length"][-1] += 7

    _edit_table(root / INDEX, lambda c: again(c, False))
    ds = open_dataset(root)
    assert [v.episode for v in ds.videos] == [0, 1, 2]  # once
    (p,) = ds.problems
    assert p.episode == 1 and "listed 2 times (row 1, row 3)" in p.message
    assert "measured once" in p.message
    _edit_table(root / INDEX, lambda c: c["length"].__setitem__(3, c["length"][3] + 7))
    ds = open_dataset(root)
    assert [v.episode for v in ds.videos] == [0, 2]  # which of the two is right is unknown
    (p,) = ds.problems
    assert p.episode == 1 and "differ" in p.message and "not measured" in p.message


def test_a_v2_episode_listed_twice_is_said(made) -> None:
    root = _copy(made, "v21", "v2_twice")
    path = root / "meta" / "episodes.jsonl"
    lines = path.read_text().splitlines()
    path.write_text("\n".join([*lines, lines[2]]) + "\n")
    ds = open_dataset(root)
    (p,) = ds.problems
    assert p.episode == 2 and "listed 2 times (line 3, line 4)" in p.message


@pytest.mark.parametrize(
    "end, value, says",
    [
        ("from_timestamp", float("nan"), "from_timestamp nan is not a time"),
        ("to_timestamp", 0.5, "runs backwards"),
        ("from_timestamp", -1.0, "before the file's start"),
    ],
    ids=["nan", "backwards", "negative"],
)
def test_a_window_that_is_not_one_is_the_episodes_problem(made, end, value, says) -> None:
    """(A NaN from_timestamp decoded the whole file from its start: 90 frames for a 30-frame
    episode, reported clean.)"""
    root = _copy(made, "v3", f"window_{end}_{value}")
    _edit_table(root / INDEX, lambda c: c[f"videos/{CAM}/{end}"].__setitem__(2, value))
    ds = open_dataset(root)
    assert ds.episodes == [0, 1]
    (p,) = ds.problems
    assert p.episode == 2 and says in p.message and CAM in p.message


# -- the data's timestamps ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def lagging(tmp_path_factory):
    """Two 4-s episodes (a lag needs 2.9 s), the camera 100 ms late in episode 1."""
    root = tmp_path_factory.mktemp("lag") / "ds"
    write_h264_dataset(root, 2, (4.0, 4.0), version="v3.0", faults=Faults(lag_ms={1: 100.0}))
    return root


def _break_clock(root, episode: int, row: int, back_s: float) -> None:
    def edit(c) -> None:
        ts = np.asarray(c["timestamp"], np.float64)
        mine = (np.asarray(c["episode_index"]) == episode) & (np.asarray(c["frame_index"]) >= row)
        c["timestamp"] = (
            (ts - back_s * mine).tolist()
            if np.isfinite(back_s)
            else [np.nan if m else t for t, m in zip(ts, mine, strict=True)]
        )

    _edit_table(root / DATA, edit)


def test_timestamps_going_backwards_are_said_and_the_lag_measured_before_them(
    lagging, tmp_path
) -> None:
    """Episode 1's timestamps go back 1 s at 3.5 s: said (file, episode, row), and its 100-ms
    lag measured on the 3.5 s before (it read -400 ms, and a drift of 1 s, before)."""
    root = tmp_path / "ds"
    shutil.copytree(lagging, root)
    _break_clock(root, 1, 105, 1.0)
    res = _run(root, tmp_path / "out")
    (line,) = res.problems
    assert f"{DATA} (episode 1)" in line and "goes backwards at row 105" in line
    rows = _rows(res)
    # the lag's estimate on one out-and-back stroke: 96-98 ms measured here (the whole clean
    # episode gives 97); within 30 ms as tests/analysis/dataset/test_dataset_faults.py allows (the
    # peak: its interval on one stroke may fill the search, and lag_ms is then left out)
    assert rows[1]["lag_peak_ms"] == pytest.approx(100, abs=30)
    assert rows[1]["drift_end_ms"] is None  # no last timestamp to hold the video's end against
    assert "drift" not in rows[1]["flags"]


def test_timestamps_broken_early_say_the_lag_cannot_be_measured(lagging, tmp_path) -> None:
    root = tmp_path / "ds"
    shutil.copytree(lagging, root)
    _break_clock(root, 1, 40, float("nan"))
    res = _run(root, tmp_path / "out")
    (line,) = res.problems
    assert "(episode 1)" in line and "timestamp nan at row 40 is not a time" in line
    row = _rows(res)[1]
    assert row["lag_ms"] is None
    assert "shorter than" in row["lag_note"] and "before the data's clock breaks" in row["lag_note"]


# -- --episodes and the output ----------------------------------------------------------------
@pytest.mark.parametrize("episodes", ["99", "-1", "1,99"])
def test_episodes_naming_no_episode_of_the_dataset_are_an_error(made, episodes) -> None:
    with pytest.raises(UserError, match=r"--episodes: .*not an episode of"):
        _run(made / "v3", made / "o_eps", episodes=episodes, fail_on="all")
    args = ["--out", str(made / "o_eps"), "--episodes", episodes, "--fail-on", "all"]
    proc = run_in_process("analysis", "dataset", str(made / "v3"), *args)
    assert_one_line_error(proc, "--episodes", "not an episode of", "indices 0-2")


def _on_a_small_disk(
    made, disk, size_kb: int, out, before: str = ""
) -> subprocess.CompletedProcess:
    """The command with ``disk`` a tmpfs of ``size_kb`` (a private mount, in a user
    namespace); ``before``: a shell command run on it first."""
    if (
        shutil.which("unshare") is None
        or subprocess.run(["unshare", "-rm", "true"], capture_output=True).returncode
    ):
        pytest.skip("no user namespaces here: a small disk cannot be mounted")
    script = (
        f'mount -t tmpfs -o size={size_kb}k tmpfs "$1" && {before or "true"} && shift && exec "$@"'
    )
    cmd = [
        sys.executable,
        "-m",
        "analysis",
        "dataset",
        str(made / "v3"),
        *flags("--jobs 1 --fov-deg 60", out=out),
    ]
    return subprocess.run(
        ["unshare", "-rm", "sh", "-c", script, "sh", str(disk), *cmd],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )


def _the_disk_is_full(proc, out) -> None:
    assert proc.returncode == 2, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if "error" in ln]
    assert len(errors) == 1, proc.stderr
    assert str(out) in errors[0] and "the disk is full" in errors[0], errors[0]
    assert "Traceback" not in proc.stderr and "file-000.mp4" not in proc.stderr


def test_a_full_output_disk_is_the_runs_error_not_the_videos(made, tmp_path) -> None:
    """The output on a 16-kB disk: the first episode's result does not fit. One line naming
    the output and the full disk, where it was a problem of every episode's video (and then
    Arrow's own message)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    out = disk / "out"
    _the_disk_is_full(_on_a_small_disk(made, disk, 16, out), out)


def test_a_disk_that_fills_as_the_tables_are_written_is_the_runs_error(made, tmp_path) -> None:
    """Every episode's result read back from an earlier run, on a disk with 16 kB left for
    the tables: one line naming the output and the full disk."""
    done = tmp_path / "done"
    _run(made / "v3", done, fov_deg=60.0)
    results = list((done / "episode_results").iterdir())
    pages = sum(-(-p.stat().st_size // 4096) for p in results)  # tmpfs holds whole pages
    disk = tmp_path / "disk"
    disk.mkdir()
    out = disk / "out"
    copy = f'mkdir "$1/out" && cp -r {done / "episode_results"} "$1/out/"'
    proc = _on_a_small_disk(made, disk, 4 * pages + 16, out, copy)
    _the_disk_is_full(proc, out)
    assert "read back" in proc.stderr  # the results were there: the tables filled the disk
