"""One clip on every core: decoding, the native metrics and the resize as a pipeline of
threads give the table a plain loop gives, bit for bit; a chosen set of metrics gives the
same values as all of them; the pipeline hands on its errors and stops its threads."""

from __future__ import annotations

import random
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from analysis.complexity.command import ComplexitySettings
from analysis.complexity.meter import METRICS, parse_metrics
from analysis.complexity.source_metrics import measure_video
from tests.analysis.complexity.test_native_metrics import FOV
from tests.helpers import write_pan
from vdc.pipeline import pipelined


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    # 40 frames: more than one queue's depth in flight, 7-px pan so that every metric moves
    return write_pan(tmp_path_factory.mktemp("pipe") / "pan.mp4", 384, 240, 40, step_px=7)


def test_the_pipeline_gives_the_plain_loops_table_bit_for_bit(clip, monkeypatch) -> None:
    every = ComplexitySettings(fov_deg=FOV, metrics="all", model="avdm")
    tables = {}
    for threads in ("1", "3"):  # 1: the plain loop; 3: decoding, metrics, resize in threads
        monkeypatch.setenv("VDC_WORKER_THREADS", threads)
        tables[threads] = measure_video(str(clip), every, "pan").table
    one, three = tables["1"], tables["3"]
    assert one.height == 40 and list(one.columns[4:15]) == list(METRICS)
    assert one["omega_dps"].drop_nulls().len() > 30 and one["edge_density"].min() > 0
    assert three.equals(one)  # every column, every bit
    # a chosen set: the same values as when every metric is computed (one SI/TI variant's
    # sums do not depend on the other's)
    monkeypatch.setenv("VDC_WORKER_THREADS", "3")
    few = measure_video(str(clip), ComplexitySettings(fov_deg=FOV, metrics="ti_p910"), "pan")
    assert few.table.columns[4:-3] == ["ti_p910"]
    assert few.table["ti_p910"].equals(one["ti_p910"])


def test_metric_names_are_checked() -> None:
    assert parse_metrics("all") == METRICS
    assert parse_metrics(" ti_p910, si_p910 ") == ("si_p910", "ti_p910")  # the tables' order
    for bad in ("si", "", "all,si_p910"):
        with pytest.raises(ValueError, match="--metrics"):
            ComplexitySettings(metrics=bad)


def test_the_pipeline_hands_on_errors_and_stops_its_threads() -> None:
    before = threading.active_count()

    def square(x: int) -> int:
        if x == 7:
            raise ArithmeticError("seven")
        return x * x

    with pytest.raises(ArithmeticError, match="seven"):
        list(pipelined(range(100), [square, lambda y: y + 1]))
    assert [y for y in pipelined(range(5), [square])] == [0, 1, 4, 9, 16]
    early = pipelined(iter(range(10**9)), [square], depth=2)  # endless: closed after 3
    assert [next(early) for _ in range(3)] == [0, 1, 4]
    early.close()
    assert threading.active_count() == before  # every thread joined
    out = list(pipelined((np.full(3, i) for i in range(20)), [np.sum]))
    assert out == [3 * i for i in range(20)]


def test_the_cheaper_area_resize_is_opencvs_within_a_level(clip) -> None:
    """vdc.resize against cv2.INTER_AREA on the decoded frames of a real clip, at the working
    raster and at other ratios: at most one level apart on a few pixels (float64 against
    float32 sums rounding a value near a half level apart); the AVDM's and the flow's readings
    on the two rasters agree to 0.5 % per frame (measured: 0.02 % and 0.04 % at most)."""
    import cv2

    from analysis.complexity.meter import ComplexityMeter
    from vdc.recording import camera_model_context, working_size
    from vdc.resize import area_resize
    from vdc.sources import open_reader

    reader = open_reader(str(clip))
    grey = [f.luma for f in reader.frames()]
    reader.close()
    h, w = working_size(240, 384, FOV)
    for size in ((h, w), (37, 61), (120, 192), (4, 8)):
        ours = np.stack([area_resize(g, size) for g in grey])
        cv = np.stack([cv2.resize(g, size[::-1], interpolation=cv2.INTER_AREA) for g in grey])
        d = np.abs(ours.astype(int) - cv)
        assert d.max() <= 1 and np.mean(d > 0) < 1e-3, (size, d.max(), np.mean(d > 0))
    ctx = camera_model_context(w, h, 25.0, FOV)
    s = ComplexitySettings(fov_deg=FOV, model="avdm", metrics="omega_dps,flow_dps")
    t, rep = np.arange(len(grey)) / 25.0, np.zeros(len(grey), bool)
    read = {}
    for name, fn in (
        ("ours", lambda g: area_resize(g, (h, w))),
        ("cv", lambda g: cv2.resize(g, (w, h), interpolation=cv2.INTER_AREA)),
    ):
        meter = ComplexityMeter(25.0, float(ctx["deg_per_px"]), s, ctx)
        read[name] = meter.update(np.stack([fn(g) for g in grey]), t, rep)
    for m in ("omega_dps", "flow_dps"):
        a, b = read["ours"][m][2:], read["cv"][m][2:]
        np.testing.assert_allclose(a, b, rtol=0.005, err_msg=m)


@pytest.mark.parametrize("first_out", [0, 6])
def test_reading_again_gives_the_full_range_values_of_a_second_pass(tmp_path, first_out) -> None:
    """An untagged clip whose luma leaves 16..235 at frame ``first_out`` (batches of 4): the
    batcher that reads the file again for the frames before it (``reopen``, as the command
    does) gives the native metrics of the one that measures every frame in full range beside,
    bit for bit, and no second reading happens when none is needed."""
    from tests.vdc.test_color_range import encode_luma
    from vdc.frame_batches import FrameBatcher
    from vdc.sources import open_reader

    path = encode_luma(tmp_path / "late.mp4", [(20, 230)] * first_out + [(44, 246)] * 4, None)
    got, reopened = {}, []

    def reopen():
        reopened.append(1)
        return open_reader(str(path))

    for name, again in (("beside", None), ("again", reopen)):
        reader = open_reader(str(path))
        b = FrameBatcher(reader, (62, 99), 25.0, batch_frames=4, color_range="auto", reopen=again)
        rows = np.concatenate([fb.native_metrics for fb in iter(b.next_batch, None)])
        got[name] = (rows, b.p910_late_corrections(), b.color_ranges())
        reader.close()
    assert got["again"][2]["color_range_p910"] == "full"
    for a, b in zip(got["again"][:2], got["beside"][:2], strict=True):
        np.testing.assert_array_equal(a, b)
    assert len(got["again"][1]) == first_out  # every frame before the excursion
    assert len(reopened) == (1 if first_out else 0)


@pytest.mark.parametrize(("reopen", "jitter"), [(False, False), (True, False), (True, True)])
def test_frames_measured_on_several_threads_give_the_plain_loops_bits(
    tmp_path, reopen, jitter
) -> None:
    """An untagged clip whose luma leaves 16..235 at frame 5 (so the P.910 range changes
    while later frames are being measured on other threads): the batcher that measures each
    frame on 3 threads (``threads=3``: decoding in its own thread, the frames' metrics and
    resize side by side, finished in order) gives the plain loop's native metrics, images,
    full-range corrections and ranges, bit for bit; with every metric and without ``reopen``
    (a camera's full-range values beside each frame) or with it (a file read again).
    ``jitter``: each frame's measuring waits 0-3 ms first (seeded), so frames finish out of
    order, the decoder runs ahead and the range changes while several are in flight."""
    from tests.vdc.test_color_range import encode_luma
    from vdc.frame_batches import FrameBatcher
    from vdc.sources import open_reader

    path = encode_luma(tmp_path / "late.mp4", [(20, 230)] * 5 + [(44, 246)] * 19, None)
    got = {}
    for threads in (1, 3):
        reader = open_reader(str(path))
        again = (lambda: open_reader(str(path))) if reopen else None
        b = FrameBatcher(
            reader,
            (62, 99),
            25.0,
            batch_frames=4,
            threads=threads,
            measure_on_threads=True,
            reopen=again,
        )
        if jitter:
            measure, rng = b.meter.measure, random.Random(threads)

            def late(*args, measure=measure, rng=rng):
                time.sleep(rng.choice((0.0, 0.001, 0.003)))
                return measure(*args)

            b.meter.measure = late
        batches = list(iter(b.next_batch, None))
        got[threads] = (
            np.concatenate([fb.native_metrics for fb in batches]),
            np.concatenate([fb.images for fb in batches]),
            b.p910_late_corrections(),
            b.color_ranges(),
        )
        b.close()
        reader.close()
    assert got[1][3]["color_range_p910"] == "full" and len(got[1][2]) == 5
    assert np.isfinite(got[1][0]).sum() > 24 * 5  # the metrics were computed
    for a, b in zip(got[3][:3], got[1][:3], strict=True):
        np.testing.assert_array_equal(a, b)
    assert got[3][3] == got[1][3]


def test_ordered_map_keeps_order_hands_on_errors_and_stops() -> None:
    from vdc.pipeline import ordered_map

    before = threading.active_count()

    def slow_square(x: int) -> int:
        time.sleep(0.001 * (x % 3))  # later items finish first: the order must hold anyway
        if x == 11:
            raise ArithmeticError("eleven")
        return x * x

    assert list(ordered_map(slow_square, range(10), threads=3)) == [x * x for x in range(10)]
    with pytest.raises(ArithmeticError, match="eleven"):
        list(ordered_map(slow_square, range(100), threads=3))
    early = ordered_map(slow_square, pipelined(iter(range(10**9)), []), threads=2)
    assert [next(early) for _ in range(4)] == [0, 1, 4, 9]
    early.close()  # the endless source's thread and the measuring threads end
    assert threading.active_count() == before


def test_a_collection_hands_out_its_largest_clips_first(tmp_path, clip) -> None:
    """The pool takes tasks in the order given: the largest files first, sources that are
    not files (an image-sequence pattern) last, equal sizes in their own order."""
    from analysis.complexity.source_metrics import largest_first

    small = write_pan(tmp_path / "small.mp4", 64, 48, 4, step_px=7)
    big = write_pan(tmp_path / "big.mp4", 384, 240, 60, step_px=7)
    assert big.stat().st_size > clip.stat().st_size > small.stat().st_size
    tasks = [{"source": str(p)} for p in (small, str(tmp_path / "f%03d.png"), clip, big)]
    order = [t["source"] for t in largest_first(tasks)]
    assert order == [str(big), str(clip), str(small), str(tmp_path / "f%03d.png")]
