"""A camera's frame rate as its evidence agrees (:func:`agreed_rate`): info.json's ``fps`` and
a camera's own ``video.fps``, held against the rate its video's frame times
(:func:`stream_rate`) and the data's timestamps (:func:`data_rate`) show."""

from __future__ import annotations

import math
from typing import Any

import av
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

# two rates agree within this share of the larger: NTSC's 30000/1001 against 30 is 0.1 %, a
# median frame interval on a 90 kHz clock or from float32 timestamps is exact to 0.01 %, and
# a stated rate off by a factor (15 or 60 for 30) is 50 % or more; past 2 % the stated rate
# would miscount a frame every 50
RATE_TOL = 0.02
RATE_SAMPLE = 600  # frame intervals enough for a rate's median (the first ones of a file)


def _median_rate(intervals: np.ndarray) -> float | None:
    """1 / the median of the positive, finite ``intervals`` (s), or None without any;
    rounded to a thousandth (a 90 kHz clock resolves a 30-fps interval to 0.01 fps, float32
    timestamps to about 0.001: finer digits are the clock's rounding, not the rate)."""
    ok = intervals[np.isfinite(intervals) & (intervals > 0)]
    return round(float(1.0 / np.median(ok)), 3) if len(ok) else None


def stream_rate(path: str) -> float | None:
    """The video's own rate (frames/s): 1 / the median interval between its first frames'
    presentation times (packets demuxed, none decoded), or None where it cannot be read."""
    try:
        with av.open(path) as c:
            s = c.streams.video[0]
            # read while the file is open: the stream belongs to the container, freed at close
            base = float(s.time_base or 0)
            pts = []
            for packet in c.demux(s):
                if packet.pts is not None:
                    pts.append(packet.pts)
                if len(pts) > RATE_SAMPLE:
                    break
    except (OSError, av.FFmpegError, IndexError):
        return None  # the episode's own problem, said when it is measured
    times = np.sort(np.asarray(pts, np.float64)) * base
    return _median_rate(np.diff(times))


def data_rate(paths: list[str]) -> float | None:
    """The data's rate (frames/s): 1 / the median interval between consecutive timestamps of
    an episode (in frame order), over the first of ``paths`` that can be read."""
    for path in paths:
        try:
            t = pq.read_table(path, columns=["episode_index", "frame_index", "timestamp"])
        except (OSError, pa.ArrowException):
            continue  # the episode's own problem, said when it is measured
        e = t["episode_index"].to_numpy().astype(np.int64)
        f = t["frame_index"].to_numpy().astype(np.int64)
        ts = t["timestamp"].to_numpy().astype(np.float64)
        order = np.lexsort((f, e))
        e, ts = e[order], ts[order]
        same = e[1:] == e[:-1]
        rate = _median_rate(np.diff(ts)[same])
        if rate is not None:
            return rate
    return None


def agreed_rate(evidence: list[tuple[str, float | None]]) -> tuple[float, bool]:
    """(the rate to measure at, whether all the evidence agrees) from ``evidence``: (what
    says it, its rate or None), the stated rate first, then the measured ones. The rate is
    the one that agrees with the most others (within :data:`RATE_TOL`): the stated one where
    it is among them, else the first measured one that is; where none agree, the first
    measured (what the frames' own times say)."""
    known = [(name, r) for name, r in evidence if r is not None]

    def agree(a: float, b: float) -> bool:
        return abs(a - b) <= RATE_TOL * max(a, b)

    votes = [sum(agree(r, q) for _, q in known) for _, r in known]
    if all(v == len(known) for v in votes):
        return known[0][1], True
    best = max(votes)
    if best == 1 and len(known) > 1:  # nothing agrees: the measured evidence, not the claim
        return known[1][1], False
    return next(r for (_, r), v in zip(known, votes, strict=True) if v == best), False


def own_rate(info: dict[str, Any], cam: str) -> float | None:
    """``video.fps`` in info.json's features for ``cam`` (LeRobot's per-camera video info),
    or None where it is not a rate."""
    feat = info.get("features", {}).get(cam)
    own = (feat.get("info") or {}).get("video.fps") if isinstance(feat, dict) else None
    ok = isinstance(own, (int, float)) and not isinstance(own, bool) and math.isfinite(own)
    return float(own) if ok and own > 0 else None
