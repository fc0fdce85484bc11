"""A robot-learning dataset at the decoder's pace: ``vdc-analyse dataset`` end to end on a
LeRobot v3.0 dataset of 480×640 AV1 at 30 fps (LeRobot's encoder settings: libsvtav1, a key
frame every 2 frames, CRF 30), against decoding alone and against the dataset graders' own
approach (the metadata and the first frame of at most 20 video files), all in the same run.

Run: ``python benchmarks/bench_dataset.py`` (a few minutes; ``--episodes`` and ``--seconds``
set the dataset's size, ``--runs`` how many times each is timed: the least counts). It writes
the dataset with ``analysis.dataset.synthetic`` (a real photograph, a moving object, one
camera) to a temporary folder, then measures, interleaved run by run (so a burst of the
machine's other load falls on all of them alike):

1. decoding alone: every episode's window decoded with plain PyAV (its libdav1d decoder on
   one thread, the luma planes touched), in this process (the floor every path shares);
2. ``dataset`` with the default metrics (``--fov-deg 70``: the AVDM and the optic flow too) and
   without a field of view (the pixel metrics alone), on 2 pool workers, the whole command
   (layout, decoding, metrics, flags, tables, page, recordings) each time into a fresh folder,
   as multiples of real time per camera (the camera's seconds of video over the wall-clock
   seconds) and as a share of decoding's pace (decoding alone on one core over the command
   on two: 2.0 would be the decoder's pace on each of the two cores). With the default metrics
   also on half the episodes (``--episodes``): the difference is the marginal pace, the fixed
   costs (the workers' start-up, the page's figure, the tables) cancelled;
3. the graders' approach (metadata, then the first frame of at most 20 files), its time, and
   what it finds of the faults of the test dataset (``STANDARD_FAULTS``) beside what
   ``dataset`` finds.

Every figure is wall-clock time on whatever else the machine runs, the least of ``--runs``;
CPU seconds are printed beside (this process, its children and the pool's workers, which are
the fork server's children). Target (issue 62): at least 15× real time per camera on 2 cores
with the default metrics, printed beside two decoders' pace (twice decoding alone on one core,
about 27× on the project's machine) and with the load average before and after the runs.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import av
import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# only the dataset's layout at the top: a pool worker imports its pool's main script again
# (multiprocessing prepares each worker so), and the command's own module (its page, Rerun,
# the statistics) cost each worker about 0.7 s of CPU that ``vdc-analyse dataset`` (whose
# main script imports vdc.launch alone) and a script that does ``import vdc`` do not pay
from cpu_time import cpu_s  # noqa: E402  (benchmarks/cpu_time.py, beside this script)

from analysis.dataset.layout import open_dataset  # noqa: E402
from analysis.dataset.window import EDGE_S  # noqa: E402


def decode_alone(root: Path) -> tuple[float, float, int]:
    """(wall s, CPU s, frames): every episode's window decoded with plain PyAV on one thread
    (libdav1d, FFmpeg's first AV1 decoder, otherwise starts threads for every core), the Y
    plane touched."""
    ds = open_dataset(root)
    t0, c0, n = time.perf_counter(), time.process_time(), 0
    for v in ds.videos:
        with av.open(v.path) as c:
            s = c.streams.video[0]
            s.thread_type = "NONE"
            s.codec_context.thread_count = 1
            if v.from_s > 0:
                c.seek(int(v.from_s / s.time_base), stream=s, backward=True)
            for fr in c.decode(s):
                t = fr.time
                if t < v.from_s - EDGE_S:
                    continue
                if v.to_s is not None and t >= v.to_s - EDGE_S:
                    break
                n += fr.planes[0].buffer_size > 0
    return time.perf_counter() - t0, time.process_time() - c0, n


def graders(root: Path, max_files: int = 20) -> tuple[float, dict]:
    """The graders' approach: info.json and the episode index, then each video file's
    container header and first frame (at most ``max_files``); what it can judge: whether a
    file's frame count and duration match the lengths of the episodes it holds."""
    t0 = time.perf_counter()
    info = json.loads((root / "meta" / "info.json").read_text())
    index = pq.read_table(next((root / "meta" / "episodes").glob("chunk-*/file-*.parquet")))
    lengths = index["length"].to_pylist()
    files = sorted((root / "videos").rglob("*.mp4"))[:max_files]
    found = {}
    for f in files:
        with av.open(str(f)) as c:
            s = c.streams.video[0]
            next(c.decode(s))  # the first frame: decodable
            stated = s.frames or round(float(s.duration * s.time_base) * info["fps"])
        found[str(f.relative_to(root))] = {"frames": stated, "sum_of_lengths": sum(lengths)}
    return time.perf_counter() - t0, found


def profile(
    root: Path, out: Path, fov: float | None, episodes: str | None = None
) -> tuple[float, float, object]:
    """(wall s, CPU s, result) of ``dataset`` on ``root`` into a fresh ``out``."""
    from analysis.dataset import DatasetSettings, dataset  # lazy: see the imports above

    shutil.rmtree(out, ignore_errors=True)  # no result kept from an earlier run is reused
    c0, t0 = cpu_s(), time.perf_counter()
    res = dataset(root, DatasetSettings(fov_deg=fov, jobs=2, episodes=episodes), out)
    return time.perf_counter() - t0, cpu_s() - c0, res


def main() -> None:
    from analysis.dataset.synthetic import STANDARD_FAULTS, Faults, write_dataset  # lazy: above

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--runs", type=int, default=3, help="times each is timed (the least counts)")
    args = ap.parse_args()
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "ds480"
        print(
            f"writing {args.episodes} episodes x {args.seconds:g} s of 480x640 AV1 at 30 fps ...",
            flush=True,
        )
        write_dataset(
            root,
            episodes=args.episodes,
            shape=(480, 640),
            seconds=(args.seconds, args.seconds),
            faults=Faults(),
        )
        video_s = args.episodes * args.seconds
        half = ",".join(str(e) for e in range(args.episodes // 2))
        # the AVDM's calibration for this raster: fitted once and cached (vdc.calibration_store),
        # as any first use of a raster; not part of a dataset's pace
        profile(root, Path(tmp) / "warm", 70.0, "0")
        runs: dict[str, list[tuple[float, float]]] = {}
        kinds = {"default": (70.0, None), "half": (70.0, half), "pixel": (None, None)}
        for r in range(args.runs):
            wall, cpu, frames = decode_alone(root)
            runs.setdefault("decode", []).append((wall, cpu))
            for kind, (fov, eps) in kinds.items():
                wall, cpu, res = profile(root, Path(tmp) / "out", fov, eps)
                runs.setdefault(kind, []).append((wall, cpu))
                if kind == "half":
                    half_frames = int(res.episodes["frames_decoded"].sum())
            print(
                f"run {r + 1}: " + ", ".join(f"{k} {v[-1][0]:.2f} s" for k, v in runs.items()),
                flush=True,
            )
        best = {k: min(v) for k, v in runs.items()}
        dec_s, dec_cpu = best["decode"]
        print(
            f"\n{frames} frames, {video_s:g} s of video per camera (1 camera); the least of "
            f"{args.runs} runs, load average {load_before:.1f} before, "
            f"{os.getloadavg()[0]:.1f} at the end"
        )
        print(f"decoding alone, 1 core      : {dec_s:6.2f} s  {video_s / dec_s:6.1f}x real time "
              f"({dec_cpu * 1000 / frames:.2f} ms CPU per frame)")  # fmt: skip
        for kind, what in (
            ("default", "default metrics (fov 70)"),
            ("pixel", "pixel metrics (no fov) "),
        ):
            wall, cpu = best[kind]
            print(f"dataset, {what}, 2 workers: {wall:6.2f} s  {video_s / wall:6.1f}x real "
                  f"time per camera ({cpu:.1f} CPU s, {cpu * 1000 / frames:.2f} ms per frame; "
                  f"{dec_s / wall:.2f} of decoding's pace)")  # fmt: skip
        pace = video_s / best["default"][0]
        two = 2 * video_s / dec_s
        print(f"target: the default metrics >= 15x real time per camera on 2 cores: {pace:.1f}x "
              f"({'met' if pace >= 15 else 'not met'}); two decoders' pace (2 x decoding alone "
              f"on 1 core) {two:.1f}x, the command at {pace / two:.2f} of it")  # fmt: skip
        # the same by CPU time: what two free cores would give with the command's CPU spread
        # evenly (a share of the machine the scheduler gives this session does not enter it)
        cpu_pace = 2 * video_s / best["default"][1]
        print(f"  by CPU: {best['default'][1] * 1000 / frames:.2f} ms a frame against decoding "
              f"alone's {dec_cpu * 1000 / frames:.2f}: {cpu_pace:.1f}x real time on two free "
              f"cores, {cpu_pace / (2 * video_s / dec_cpu):.2f} of two decoders' pace by CPU "
              f"({2 * video_s / dec_cpu:.1f}x)")  # fmt: skip
        d_wall = best["default"][0] - best["half"][0]
        d_cpu = best["default"][1] - best["half"][1]
        d_frames = frames - half_frames
        if d_wall > 0 and d_frames > 0:
            d_video = d_frames / 30.0
            print(f"  marginal (all {args.episodes} episodes against {args.episodes // 2}: the "
                  f"fixed costs cancel): {d_video / d_wall:.1f}x real time per camera "
                  f"({d_cpu * 1000 / d_frames:.2f} ms CPU per frame; decoding alone "
                  f"{dec_cpu * 1000 / frames:.2f}); fixed costs "
                  f"{best['default'][0] - frames * d_wall / d_frames:.2f} s")  # fmt: skip
        # the episodes' recordings reference the video (its packets), never decoded frames
        rec_b = sum(p.stat().st_size for p in (Path(tmp) / "out" / "recordings").glob("*.rrd"))
        vid_b = sum(p.stat().st_size for p in (root / "videos").rglob("*.mp4"))
        print(
            f"episode recordings: {rec_b / 1e6:.1f} MB for {vid_b / 1e6:.1f} MB of video "
            f"({rec_b / vid_b:.2f}x; the decoded RGB frames: {frames * 480 * 640 * 3 / 1e6:.0f} "
            "MB)"
        )
        g_s, found = graders(root)
        print(f"graders' approach (metadata + first frames): {g_s:.3f} s")
        # what each approach finds on the test dataset (96x128, one fault per episode)
        small = Path(tmp) / "faults"
        write_dataset(small, faults=STANDARD_FAULTS)
        _, found = graders(small)
        _, _, res = profile(small, Path(tmp) / "out_small", None)
        flagged = {r["episode_index"]: r["flags"] for r in res.episodes.iter_rows(named=True)}
        faulty = [e for e in range(len(flagged)) if not STANDARD_FAULTS.clean(e)]
        mismatch = [f for f, v in found.items() if v["frames"] != v["sum_of_lengths"]]
        print(f"\non the test dataset ({len(faulty)} faulty episodes of {len(flagged)}):")
        print(f"  graders' approach: {len(mismatch)} file(s) whose frame count differs from the "
              f"episodes' lengths ({', '.join(mismatch) or 'none'}); no episode named, no "
              "pixel read past the first frame")  # fmt: skip
        hits = sum(1 for e in faulty if flagged[e])
        false = sum(1 for e, f in flagged.items() if f and STANDARD_FAULTS.clean(e))
        print(f"  dataset: {hits} of {len(faulty)} faulty episodes flagged, {false} clean ones")
        for e in faulty:
            # a 100-ms lag is left unflagged by design: one stroke's interval fills the search
            print(f"    episode {e}: {flagged[e] or 'not flagged'}")


if __name__ == "__main__":
    main()
