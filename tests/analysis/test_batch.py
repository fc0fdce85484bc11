"""``vdc-analyse batch`` and ``summarise``: parts, resume, shards, faults, the local pool."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import polars as pl

from analysis.batch import model_slug
from tests.helpers import assert_one_line_error, flags, kill_a_worker_mid_batch, run_text
from tests.in_process import run_in_process

MODELS = ("avdm", "avdm:beta=0.5", "lgmd-plus")
TABLES = ("frames", "model_outputs", "events", "summary")


def _models() -> list[str]:
    return [a for m in MODELS for a in ("--model", m)]


def _read(folder: Path) -> dict[str, pl.DataFrame]:
    return {n: pl.read_parquet(folder / f"{n}.parquet") for n in TABLES}


def _same_tables(a: dict[str, pl.DataFrame], b: dict[str, pl.DataFrame]) -> None:
    for name in TABLES:
        assert a[name].columns == b[name].columns, name
        assert a[name].equals(b[name]), name  # same recordings, same code, one machine


def test_batch_writes_the_tables_tables_writes_and_resumes(recordings, tmp_path: Path) -> None:
    recs = [str(recordings[k]) for k in ("phases", "tf3_a", "tf3_b")]
    proc = run_in_process("analysis", "tables", *recs, *_models(), "--out", str(tmp_path / "t"))
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "b"
    proc = run_in_process("analysis", "batch", *recs, *_models(), "--out", str(out), "--jobs", "2")
    assert proc.returncode == 0, proc.stderr
    assert "9 tasks: 0 already done, 9 ran, 0 failed" in proc.stdout
    _same_tables(_read(out), _read(tmp_path / "t"))
    # the hive layout: one directory per (recording, variant), no '=' inside a value
    parts = sorted(out.glob("parts/recording_id=*/model=*/model_outputs.parquet"))
    assert len(parts) == 9
    assert {p.parent.name for p in parts} == {f"model={model_slug(m)}" for m in MODELS}
    assert all(p.parent.name.count("=") == 1 for p in parts)
    one = pl.read_parquet(parts[0])
    assert one["recording_id"].n_unique() == 1 and one["model"].n_unique() == 1  # ids inside
    # a re-run finds everything done; --force recomputes, to the same rows
    stamp = parts[0].stat().st_mtime_ns
    again = run_in_process("analysis", "batch", *recs, *_models(), "--out", str(out))
    assert again.returncode == 0, again.stderr
    assert "9 already done, 0 ran" in again.stdout and parts[0].stat().st_mtime_ns == stamp
    forced = run_in_process("analysis", "batch", *recs, *_models(), "--out", str(out), "--force")
    assert forced.returncode == 0 and "0 already done, 9 ran" in forced.stdout
    _same_tables(_read(out), _read(tmp_path / "t"))


def test_shards_split_the_tasks_and_summarise_joins_them(recordings, tmp_path: Path) -> None:
    recs = [str(recordings[k]) for k in ("tf3_a", "tf3_b")]
    out = tmp_path / "s"
    done = []
    for i in range(3):
        proc = run_in_process(
            "analysis",
            "batch",
            *recs,
            *_models(),
            *flags("--jobs 1", out=out, shard=f"{i}/3"),
        )
        assert proc.returncode == 0, proc.stderr
        assert "2 tasks (shard" in proc.stderr and not (out / "summary.parquet").exists()
        done.append(len(list(out.glob("parts/*/model=*/summary.parquet"))))
    assert done == [2, 4, 6]  # each shard ran its own two of the six tasks
    proc = run_in_process("analysis", "summarise", str(out))
    assert proc.returncode == 0, proc.stderr
    whole = run_in_process("analysis", "tables", *recs, *_models(), "--out", str(tmp_path / "t"))
    assert whole.returncode == 0, whole.stderr
    _same_tables(_read(out), _read(tmp_path / "t"))


def test_a_corrupt_recording_fails_its_own_tasks_only(recordings, tmp_path: Path) -> None:
    bad = tmp_path / "bad.rrd"
    bad.write_bytes(b"not a recording" * 100)
    out = tmp_path / "b"
    proc = run_in_process(
        "analysis",
        "batch",
        str(recordings["tf3_a"]),
        str(bad),
        *flags("--model avdm --model lgmd-plus", out=out),
    )
    assert proc.returncode == 1
    assert proc.stderr.count(f"FAILED {bad} ") >= 2 and "Traceback" not in proc.stderr
    assert "4 tasks: 0 already done, 2 ran, 2 failed" in proc.stdout
    failures = pl.read_parquet(out / "failures.parquet")
    assert failures.height == 2 and failures["task"].str.contains("bad.rrd").all()
    assert pl.read_parquet(out / "summary.parquet").height == 2  # the good recording's


def _children(pid: int) -> list[int]:
    kids = []
    for tid in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{tid}/children") as f:
            kids += [int(k) for k in f.read().split()]
    return kids


def _pool_workers(pid: int) -> list[int]:
    """The local pool's workers of process ``pid``: the children of its fork server (the pool
    forks its workers from a warm ``forkserver``, vdc.executors), not the resource tracker."""
    workers = []
    for kid in _children(pid):
        try:
            with open(f"/proc/{kid}/cmdline", "rb") as f:
                if b"forkserver" in f.read():
                    workers += _children(kid)
        except FileNotFoundError:
            pass
    return workers


def test_a_killed_pool_worker_loses_no_finished_part(recordings, tmp_path: Path) -> None:
    """SIGKILL one worker of the local pool mid-run: the stdlib pool breaks; the unfinished
    tasks go to a fresh pool, finished parts stay as they were, and a re-run has nothing left."""
    recs = [str(recordings[k]) for k in ("phases", "tf3_a", "tf3_b")]
    models = [
        a for m in ("avdm", "avdm:beta=0.5", "avdm:tw=6", "lgmd-plus") for a in ("--model", m)
    ]
    out = tmp_path / "b"
    rc, stdout, stderr, _killed = kill_a_worker_mid_batch(
        [*recs, *models, "--jobs", "2"],
        out,
        lambda batch_pid: next(iter(_pool_workers(batch_pid)), None),
        total=12,
    )
    # the broken pool's unfinished tasks ran in a fresh one: the run still completes
    assert rc == 0, stderr
    assert "12 tasks: 0 already done, 12 ran, 0 failed" in stdout
    assert "a worker process died" in stderr
    for part in out.glob("parts/**/*.parquet"):
        pl.read_parquet(part)  # every part is whole: written to a temporary name, then renamed
    again = run_in_process("analysis", "batch", *recs, *models, "--out", str(out))
    assert again.returncode == 0, again.stderr
    assert "12 already done, 0 ran" in again.stdout
    assert pl.read_parquet(out / "summary.parquet").height == 12 + 4  # 'phases' has 2 TFs


def test_bad_batch_input_is_one_line(tmp_path: Path, recordings) -> None:
    rec = str(recordings["tf3_a"])
    for args, message in (
        (["--shard", "3/2"], "need 0 <= I < N"),
        (["--shard", "x"], "expected I/N"),
        (["--scheduler", str(tmp_path / "none.json")], "neither tcp://"),
        (["--jobs", "0"], "--jobs: expected an integer >= 1"),
        (["--model", "nope"], "unknown model"),
    ):
        proc = run_in_process(
            "analysis", "batch", rec, "--model", "avdm", *args, "--out", str(tmp_path / "o")
        )
        assert_one_line_error(proc, message)
    proc = run_in_process("analysis", "summarise", str(tmp_path / "empty"))
    assert_one_line_error(proc, "has no finished batch parts")


def test_dask_without_the_extra_says_how_to_install_it(recordings, tmp_path: Path) -> None:
    """Dask is optional: without it (hidden from the import system here), --executor dask
    is one line naming the extra, and the local pool still works."""
    code = (
        "import sys; sys.modules['distributed'] = None\n"  # `import distributed` now fails
        "from analysis.cli import main\n"
        "raise SystemExit(main(sys.argv[1:]))\n"
    )
    args = ["batch", str(recordings["tf3_a"]), "--model", "avdm"]
    proc = run_text(
        [sys.executable, "-c", code, *args, "--out", str(tmp_path / "d"), "--executor", "dask"]
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    last = proc.stderr.splitlines()[-1]
    assert last.endswith('needs the optional extra: pip install -e ".[dask]"'), last
    proc = run_text(
        [sys.executable, "-c", code, *args, "--out", str(tmp_path / "l"), "--jobs", "1"]
    )
    assert proc.returncode == 0, proc.stderr
