"""The table-set publisher (``vdc.parquet_io.table_set``) never touches what vdc did not write.

An ``--out`` folder's other entries (the user's files, dot-files such as ``.git``, sub-folders
with their contents, the input itself) stay where they are, byte for byte and inode for inode
(never moved, linked or copied), whatever the folder is: a repository, the current folder,
a LeRobot dataset's own root; and a publisher killed with SIGKILL at any moment leaves them so
while the next writer finishes or undoes its set.
"""

from __future__ import annotations

import os
import random
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq

from tests.helpers import ROOT, assert_one_line_error, make_sim_recording, write_h264_dataset
from tests.in_process import run_in_process
from vdc.folders import OUTPUTS_MANIFEST, expand_recordings
from vdc.parquet_io import table_set

TABLES = {"frames.parquet", "model_outputs.parquet", "events.parquet", "summary.parquet"}


def user_entries(folder: Path) -> int:
    """Fill ``folder`` as a user's project: files, dot-files, a ``.git`` with contents,
    sub-folders with nested contents, a symbolic link. Returns how many entries it made."""
    made = 0
    (folder / ".git" / "objects" / "ab").mkdir(parents=True)
    (folder / ".git" / "HEAD").write_text("ref: refs/heads/main\n")
    (folder / ".git" / "objects" / "ab" / "cdef").write_bytes(os.urandom(64))
    (folder / ".notes").write_text("what I tried\n")
    (folder / ".gitattributes").write_text("*.parquet filter=lfs\n")
    made += 6
    for i in range(12):
        (folder / f"note_{i}.txt").write_text(f"note {i}\n")
        (folder / f".hidden_{i}").write_bytes(os.urandom(16))
        sub = folder / f"sub_{i}" / "deeper"
        sub.mkdir(parents=True)
        (sub.parent / "a.csv").write_text(f"x\n{i}\n")
        (sub / "b.bin").write_bytes(os.urandom(32))
        made += 6
    (folder / "link_to_note").symlink_to("note_0.txt")
    return made + 1


def snapshot(folder: Path, skip: set[str]) -> dict[str, tuple]:
    """Every entry below ``folder`` except the top-level names in ``skip`` (vdc's) and the
    manifest: its kind,
    inode and content (a link: its target), so a moved, copied or rewritten entry shows."""
    out: dict[str, tuple] = {}
    for dirpath, dirnames, filenames in os.walk(folder):
        here = Path(dirpath)
        rel_here = here.relative_to(folder)
        if rel_here.parts and rel_here.parts[0] in skip | {OUTPUTS_MANIFEST}:
            continue
        for name in dirnames + filenames:
            p = here / name
            rel = str(p.relative_to(folder))
            if not rel_here.parts and name in skip | {OUTPUTS_MANIFEST}:
                continue
            st = p.lstat()
            if p.is_symlink():
                out[rel] = ("link", st.st_ino, os.readlink(p))
            elif p.is_dir():
                out[rel] = ("dir", st.st_ino)
            else:
                out[rel] = ("file", st.st_ino, p.read_bytes())
    return out


# -- the commands ------------------------------------------------------------------------------
def test_tables_into_a_repository_keeps_its_git_notes_and_sub_folders(tmp_path: Path) -> None:
    rec = make_sim_recording(tmp_path / "run.rrd")
    res = tmp_path / "res"
    res.mkdir()
    n = user_entries(res)
    # named like staging folders but not vdc's: one beside res as an older vdc left it (a dead
    # writer's pid; it may hold the user's sub-folders), one inside without vdc's mark
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    old_style = tmp_path / f".res.staging-{dead}" / "my_sub"
    look_alike = res / ".vdc-staging-1-mine"
    for folder in (old_style, look_alike):
        folder.mkdir(parents=True)
        (folder / "keep.txt").write_text("mine\n")
    before = snapshot(res, TABLES)
    assert len(before) >= n
    for _ in range(2):  # the second run replaces vdc's own tables, and only them
        proc = run_in_process("analysis", "tables", str(rec), "--out", str(res))
        assert proc.returncode == 0, proc.stderr
        assert snapshot(res, TABLES) == before
        assert {p.name for p in res.iterdir() if p.name.endswith(".parquet")} == TABLES
        for folder in (old_style, look_alike):
            assert (folder / "keep.txt").read_text() == "mine\n"
    assert [p.name for p in res.glob(".vdc-staging-*")] == [look_alike.name]
    manifest = (res / OUTPUTS_MANIFEST).read_text()
    assert all(t in manifest for t in TABLES) and ".git" not in manifest and "note" not in manifest


def test_out_dot_in_a_project_that_holds_the_recording_writes_beside_it(tmp_path: Path) -> None:
    """``--out .`` (was a traceback) and ``--out "$PWD"`` (deleted the project's .git), in a
    repository root that holds the input: the tables are written beside its entries."""
    project = tmp_path / "project"
    project.mkdir()
    user_entries(project)
    rec = make_sim_recording(project / "run.rrd")
    before = snapshot(project, TABLES)
    for out in (".", str(project)):
        proc = run_in_process("analysis", "tables", "run.rrd", "--out", out, cwd=project)
        assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
        assert snapshot(project, TABLES) == before  # run.rrd, .git and the rest, untouched
        assert TABLES <= {p.name for p in project.iterdir()}
    # the folder is still the recording's collection: its tables are not taken as sources
    assert expand_recordings(project) == [str(rec)]


def test_a_name_the_set_writes_taken_by_a_users_file_is_refused_and_kept(tmp_path: Path) -> None:
    rec = make_sim_recording(tmp_path / "run.rrd")
    res = tmp_path / "res"
    res.mkdir()
    (res / "summary.parquet").write_text("the user's own summary\n")
    proc = run_in_process("analysis", "tables", str(rec), "--out", str(res))
    assert_one_line_error(proc, str(res / "summary.parquet"), "not vdc's")
    assert (res / "summary.parquet").read_text() == "the user's own summary\n"
    assert sorted(p.name for p in res.iterdir()) == ["summary.parquet"]  # nothing else written


def test_a_dataset_given_as_its_own_out_keeps_every_entry(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    write_h264_dataset(root, 2, (1.0, 1.0), version="v3.0", shape=(48, 64))
    (root / ".gitattributes").write_text("*.mp4 filter=lfs diff=lfs merge=lfs -text\n")
    (root / ".cache" / "huggingface").mkdir(parents=True)
    (root / ".cache" / "huggingface" / "download.lock").write_text("x")
    vdc_writes = {
        "episodes.parquet",
        "frames.parquet",
        "problems.parquet",
        "dataset.html",
        "recordings",
        "episode_results",
        "flagged_episodes.json",
    }
    before = snapshot(root, vdc_writes)
    for _ in range(2):  # the second run reads the dataset beside its own outputs
        proc = run_in_process("analysis", "dataset", str(root), "--out", str(root), "--jobs", "1")
        assert proc.returncode == 0, proc.stderr
        assert snapshot(root, vdc_writes) == before
        assert (root / "episodes.parquet").is_file()
        assert pq.read_table(root / "episodes.parquet").num_rows == 2


# -- SIGKILL at random moments -----------------------------------------------------------------
N_FILES = 60  # many entries per set: the publish (a rename each) is half of a set's time
WRITER = f"""
import sys, time
from pathlib import Path
import pyarrow as pa, pyarrow.parquet as pq
from vdc.parquet_io import table_set
out = Path(sys.argv[1])
while True:
    run = str(time.time_ns())
    with table_set(out) as stage:
        pq.write_table(pa.table({{"run": [run]}}), stage / "summary.parquet")
        (stage / "figures").mkdir()
        for i in range({N_FILES}):
            (stage / f"t{{i:03d}}.txt").write_text(run)
        for i in range(5):
            (stage / "figures" / f"f{{i}}.txt").write_text(run)
    print(run, flush=True)
"""


def vdc_names(out: Path) -> set[str]:
    """The top-level names the writer's sets use in ``out``, its staging folders included."""
    return {"figures", "summary.parquet"} | {
        p.name for pattern in ("t*.txt", ".vdc-staging-*") for p in out.glob(pattern)
    }


def vdc_set(out: Path) -> tuple[set[str], int]:
    """The run ids vdc's files in ``out`` carry, and how many files carry one."""
    ids = [p.read_text() for p in out.glob("t*.txt")]
    ids += [p.read_text() for p in (out / "figures").glob("f*.txt")]
    if (out / "summary.parquet").exists():
        ids += pq.read_table(out / "summary.parquet")["run"].to_pylist()  # whole, or unreadable
    return set(ids), len(ids)


def test_a_publisher_killed_at_random_moments_never_touches_a_user_entry(tmp_path: Path) -> None:
    """A real writer publishing sets in a loop, killed with SIGKILL at random moments over a
    folder of many user entries: after every kill the user's entries are where they were, with
    their content; the next writer's recovery (here an empty set published in this process)
    leaves one whole set, every file of one run. Kills go on until some landed mid-publish
    (a committed staging folder left behind), the case a roll-forward finishes."""
    out = tmp_path / "res"
    out.mkdir()
    user_entries(out)
    before = snapshot(out, set())
    rng = random.Random(56)
    kills = mid_publish = 0
    while kills < 8 or (mid_publish < 2 and kills < 60):
        proc = subprocess.Popen(  # this tree's vdc: -c puts the working folder first
            [sys.executable, "-c", WRITER, str(out)],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            assert proc.stdout is not None and proc.stdout.readline(), proc.stderr
            start = time.monotonic()  # a set is there to replace; the next one takes:
            proc.stdout.readline()
            time.sleep(rng.uniform(0, time.monotonic() - start))  # anywhere in the third
        finally:
            proc.kill()
            proc.communicate(timeout=30)
        kills += 1
        mid_publish += bool(list(out.glob(".vdc-staging-*/.vdc-journal.json")))
        assert snapshot(out, vdc_names(out)) == before
        with table_set(out):  # the next writer: recovers the dead one's set
            pass
        ids, n = vdc_set(out)
        assert len(ids) == 1 and n == N_FILES + 6, (len(ids), n)
        assert not list(out.glob(".vdc-staging-*"))
    assert mid_publish >= 2, (kills, mid_publish)
    assert snapshot(out, vdc_names(out)) == before


def test_a_folder_scan_skips_a_staging_folder(tmp_path: Path) -> None:
    """A killed writer's staging folder inside a collection (``--out`` the collection itself)
    holds vdc's outputs: never sources of the next run's scan."""
    rec = make_sim_recording(tmp_path / "clip.rrd")
    stale = tmp_path / ".vdc-staging-999999-x"
    stale.mkdir()
    (stale / "complexity_clip.rrd").write_bytes(rec.read_bytes())
    assert expand_recordings(tmp_path) == [str(rec)]


def test_a_batch_without_failures_keeps_a_users_failures_file(tmp_path: Path) -> None:
    """``batch`` deleted ``out/failures.parquet`` whoever wrote it when a run had no failure:
    now only vdc's own (named in the manifest) is removed."""
    rec = make_sim_recording(tmp_path / "run.rrd")
    res = tmp_path / "res"
    res.mkdir()
    (res / "failures.parquet").write_text("the user's own list\n")
    proc = run_in_process(
        "analysis", "batch", str(rec), "--model", "avdm", "--out", str(res), "--jobs", "1"
    )
    assert proc.returncode == 0, proc.stderr
    assert (res / "failures.parquet").read_text() == "the user's own list\n"
