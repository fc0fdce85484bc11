"""The capture loop: device → online model → recorder, with a clean stop on signals.

Ctrl-C or SIGTERM sets a flag; the batch in hand is finished and logged, then the recording is
closed with its footer and a ``run_end`` property saying how many frames it holds and why it
stopped. Nothing already read from the device is dropped.
"""

from __future__ import annotations

import dataclasses
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from avdm.base import Model
from avdm.errors import PluginError
from avdm.true_time import TrueTimeModel
from capture.device import Batch, CaptureDevice, Event
from capture.live_view import spawn_viewer
from capture.output import OutputClaim
from capture.recorder import Recorder, RecordingWriteError
from vdc.heartbeat import Count


@dataclasses.dataclass
class CaptureResult:
    frames: int
    events: dict[str, int]  # count per kind
    # "finished", "signal SIGINT" / "signal SIGTERM", "write error" or "link error" (a robot
    # that broke what it announced)
    stop_reason: str
    wall_time_s: float
    write_error: str | None = None
    # a model plug-in that raised (stop_reason "plug-in error"): the frames before it are kept
    plugin_error: PluginError | None = None


@dataclasses.dataclass
class RecordResult:
    """What a capture command wrote: the recording and how its run ended."""

    path: Path
    recording_id: str
    frames: int
    events: dict[str, int]
    stop_reason: str
    wall_time_s: float
    expected_frames: int | None = None  # None: a live source with no set length

    @classmethod
    def of(
        cls, path: Path, recording_id: str, res: CaptureResult, expected: int | None
    ) -> RecordResult:
        return cls(
            path,
            recording_id,
            res.frames,
            res.events,
            res.stop_reason,
            res.wall_time_s,
            expected,
            res.write_error,
            None if res.plugin_error is None else str(res.plugin_error),
        )

    @property
    def size_mb(self) -> float:
        return self.path.stat().st_size / 1e6

    @property
    def complete(self) -> bool:
        return self.stop_reason == "finished"

    write_error: str | None = None  # why the file could not take more (disk full, ...)
    plugin_error: str | None = None  # the model plug-in's failure that ended the run, one line

    @property
    def exit_status(self) -> int:
        """0 when finished; 130 / 143 when stopped by SIGINT / SIGTERM (shell convention); 1
        when the file could not take more."""
        if self.complete:
            return 0
        if self.stop_reason in ("write error", "link error", "plug-in error"):
            return 1
        return 130 if "SIGINT" in self.stop_reason else 143


@dataclasses.dataclass(frozen=True)
class CaptureOptions:
    """How every capture (sim, video, robot) writes and shows its recording: the command
    line's ``--force``, ``--connect`` / ``--spawn`` and ``--quiet``."""

    force: bool = False  # replace an existing output file
    live_url: str | None = None  # also stream to the viewer at this URL
    spawn: bool = False  # also stream to a new viewer
    progress: bool = False  # the frames counted on the heartbeat line (vdc.heartbeat), if one runs
    log: Callable[[str], None] | None = None  # gets one line on what is recorded, before the run

    def output_path(self, out: str | Path | None, recording_id: str) -> Path:
        """``out``, by default ``recordings/<recording id>.rrd``."""
        return Path(out) if out else Path("recordings") / f"{recording_id}.rrd"

    def viewer_url(self) -> str | None:
        """Where the recording streams live as well: a new viewer (``spawn``), ``live_url``,
        or nowhere (None)."""

        return spawn_viewer() if self.spawn else self.live_url


DEFAULT_CAPTURE = CaptureOptions()
REPLACE_OUTPUT = CaptureOptions(force=True)  # a campaign's run: what a killed run left is replaced


def finish_output(claim: OutputClaim, recorder: Recorder | None) -> None:
    """End a capture's claim on its output: publish the recording if the run happened (it was
    closed, or holds frames), else remove the partial file. Call in a ``finally``."""
    keep = recorder is not None and (recorder.closed or recorder.frames_logged > 0)
    claim.finish(keep=keep)


class StopFlag:
    """Set by SIGINT/SIGTERM while a capture runs."""

    def __init__(self) -> None:
        self.reason: str | None = None

    def __bool__(self) -> bool:
        return self.reason is not None


@contextmanager
def stop_on_signals() -> Iterator[StopFlag]:
    """Route SIGINT and SIGTERM to a flag for the duration of the block (main thread only)."""
    flag = StopFlag()
    if threading.current_thread() is not threading.main_thread():
        yield flag
        return

    def handler(signum: int, _frame: Any) -> None:
        flag.reason = f"signal {signal.Signals(signum).name}"

    old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield flag
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def batch_bytes(batch: Batch) -> int:
    """About what a batch adds to the file: its raw images (camera noise does not compress)
    and a margin for the scalars, events and chunk headers."""
    overhead = sum(img.nbytes for _, img in batch.overhead) if batch.overhead else 0
    return int(batch.images.nbytes + overhead + 512 * len(batch) + (64 << 10))


def _log_events(
    recorder: Recorder,
    events: list[Event],
    at: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray | None]],
) -> dict[str, int]:
    """Each kind's events logged at the frames they name, at the times ``at(frames)`` gives
    (seconds, and capture times or None); returns the number logged per kind."""
    counts: dict[str, int] = {}
    for kind in sorted({e.kind for e in events}):
        evs = [e for e in events if e.kind == kind]
        frames = np.array([e.frame for e in evs], dtype=np.int64)
        xy = np.array([[e.x_m, e.y_m] for e in evs])
        t, c = at(frames)
        recorder.log_events(kind, frames, t, xy, [e.text for e in evs], c)
        counts[kind] = len(evs)
    return counts


def log_batch(
    recorder: Recorder,
    model: Model | TrueTimeModel | None,
    batch: Batch,
    prev_t_s: float | None = None,
) -> dict[str, int]:
    """Log everything in a batch, running the host-side online ``model`` on its frames unless
    the robot already ran it on board; returns the number of events logged per kind.
    ``prev_t_s``: the time of the frame before the batch (for the first frame's interval)."""
    if len(batch) == 0:
        # events without frames (the robot's link failing before its next frame): at the
        # frame they name, at the time of the last frame logged (0 before any)
        t_last = 0.0 if prev_t_s is None else prev_t_s
        return _log_events(recorder, batch.events, lambda f: (np.full(len(f), t_last), None))
    cap = batch.capture_time_ns

    def at(frames: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Time (and capture time) of some of the batch's frames."""
        k = np.searchsorted(batch.frame, frames)
        return batch.t_s[k], (None if cap is None else cap[k])

    img_frames = batch.frame if batch.image_frame is None else batch.image_frame
    t_img, cap_img = at(img_frames)
    recorder.log_frames(img_frames, t_img, batch.images, cap_img)
    if batch.poses is not None:
        recorder.log_poses(batch.frame, batch.t_s, batch.poses, cap)
    if batch.wall_tf_hz is not None:
        recorder.log_wall_tf(batch.frame, batch.t_s, batch.wall_tf_hz, cap)
    if batch.repeat is not None:
        dropped = (
            np.zeros(len(batch), np.int64) if batch.dropped_before is None else batch.dropped_before
        )
        dt = np.diff(batch.t_s, prepend=np.nan)
        if len(dt) and prev_t_s is not None:
            dt[0] = batch.t_s[0] - prev_t_s
        recorder.log_frame_timing(batch.frame, batch.t_s, batch.repeat, dropped, dt)
    if batch.native_metrics is not None:
        recorder.log_native_metrics(batch.frame, batch.t_s, batch.native_metrics)
    for name, outputs in batch.onboard.items():
        recorder.log_model_outputs(name, batch.frame, batch.t_s, outputs, capture_ns=cap)
    if model is not None and model.name not in batch.onboard and len(batch.images):
        try:
            if isinstance(model, TrueTimeModel):  # a real camera: new frames, true time
                repeat = np.zeros(len(batch), bool) if batch.repeat is None else batch.repeat
                outputs = model.run(batch.images, t_img, repeat)
            else:
                outputs = model.run(batch.images)  # ≡ per-frame step(), bit for bit
        except PluginError as exc:  # the user's model: name the frame it failed on
            raise exc.at(img_frames) from None
        recorder.log_model_outputs(model.name, img_frames, t_img, outputs, capture_ns=cap_img)
    if batch.link_stats is not None:
        recorder.log_link_stats(
            int(batch.frame[-1]),
            float(batch.t_s[-1]),
            batch.link_stats,
            None if cap is None else int(cap[-1]),
        )
    counts = _log_events(recorder, batch.events, at)
    if batch.overhead:
        idx = np.array([f for f, _ in batch.overhead], dtype=np.int64)
        recorder.log_overhead(
            idx, np.interp(idx, batch.frame, batch.t_s), [img for _, img in batch.overhead]
        )
    return counts


def run_capture(
    device: CaptureDevice,
    model: Model | TrueTimeModel | None,
    recorder: Recorder,
    *,
    total_frames: int | None = None,
    progress: bool = True,
) -> CaptureResult:
    """Read the device to its end (or a signal), logging every batch; always closes cleanly."""

    t0 = time.perf_counter()
    frames = 0
    events: dict[str, int] = {}
    reason = "error"
    prev_t: float | None = None
    plugin_error: PluginError | None = None
    # frames counted on the command's heartbeat line (vdc.heartbeat), if it has one
    bar = Count(total_frames, "capture", "frame", quiet=not progress)
    try:
        with stop_on_signals() as stop:
            device.connect()
            try:
                while not stop:
                    batch = device.read()
                    if batch is None:
                        break
                    try:
                        recorder.reserve(batch_bytes(batch))
                        logged = log_batch(recorder, model, batch, prev_t)
                        recorder.end_batch()
                    except RecordingWriteError:
                        stop.reason = "write error"
                        break
                    except PluginError as exc:  # the run ends; what it recorded is kept
                        stop.reason, plugin_error = "plug-in error", exc
                        frames += len(batch)  # its frames were logged before the model ran
                        break
                    for kind, n in logged.items():
                        events[kind] = events.get(kind, 0) + n
                    if len(batch):
                        prev_t = float(batch.t_s[-1])
                    frames += len(batch)
                    bar.update(len(batch))
            finally:
                device.disconnect()
            # a device may end the run itself on a fault it logged (the robot's link breaking
            # its announcement): the run is then not complete
            reason = stop.reason or getattr(device, "stop_reason", None) or "finished"
    finally:
        bar.close()
        wall = time.perf_counter() - t0
        recorder.close(
            frames=frames,
            stop_reason=reason,
            complete=reason == "finished",
            wall_time_s=round(wall, 3),
        )
    return CaptureResult(frames, events, reason, wall, recorder.write_error, plugin_error)
