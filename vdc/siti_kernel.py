"""The native metrics' compiled kernel (``vdc.frame_metrics``): one pass over a frame's luma
and the previous frame's for P.910 SI and TI (float32), the legacy SI and TI (float64), the
MAFD and the range scan, each domain's sums apart so that one variant costs half of both.

The P.910 domain computes in float32 (its table, the Sobel, its square root and each row's
sums; a frame's sums in float64): 0.65 against 1.77 ms per 720p frame for float64 on this
machine, SI and TI 3-6e-9 relative from siti-tools' float64 (``benchmarks/bench_siti_kernel.py``),
far inside the three decimals siti-tools prints. Every call of one kernel with the same
argument types gives the same bits for the same frames (aligned row buffers; a kernel compiled
for other argument types may group its float32 sums otherwise, so callers that must agree bit
for bit pass the same types).
"""

from __future__ import annotations

import math

import numpy as np

from avdm.jit import kernel

_F32 = np.float32


@kernel(fastmath=True, nogil=True)
def _map_row(codes, lut, out):  # pragma: no cover - compiled
    for j in range(codes.shape[0]):
        out[j] = lut[codes[j]]


@kernel(fastmath=True, nogil=True)
def _sobel_row(r0, r1, r2, w, sums):  # pragma: no cover - compiled
    """Add the interior Sobel magnitudes of the middle row (its first ``w`` columns) to
    sums[0] (Σm) and sums[1] (Σm²)."""
    s = 0.0
    ss = 0.0
    for j in range(1, w - 1):
        gx = (r0[j + 1] + 2.0 * r1[j + 1] + r2[j + 1]) - (r0[j - 1] + 2.0 * r1[j - 1] + r2[j - 1])
        gy = (r2[j - 1] + 2.0 * r2[j] + r2[j + 1]) - (r0[j - 1] + 2.0 * r0[j] + r0[j + 1])
        m = math.sqrt(gx * gx + gy * gy)
        s += m
        ss += m * m
    sums[0] += s
    sums[1] += ss


@kernel(fastmath=True, nogil=True)
def _sobel_row32(r0, r1, r2, w, sums):  # pragma: no cover - compiled
    """:func:`_sobel_row` on float32 rows in float32 arithmetic (the P.910 domain): the row's
    sums are formed in float32 (vectorised: 16 lanes in a 512-bit register, twice 8 in
    AVX2) and added to the float64 ``sums``."""
    s = _F32(0)
    ss = _F32(0)
    two = _F32(2)
    for j in range(1, w - 1):
        gx = (r0[j + 1] + two * r1[j + 1] + r2[j + 1]) - (r0[j - 1] + two * r1[j - 1] + r2[j - 1])
        gy = (r2[j - 1] + two * r2[j] + r2[j + 1]) - (r0[j - 1] + two * r0[j] + r0[j + 1])
        x = gx * gx + gy * gy
        s += math.sqrt(x)
        ss += x
    sums[0] += s
    sums[1] += ss


@kernel(fastmath=True, nogil=True, error_model="numpy")
def _diff_row(a, prev_codes, lut, w, sums, zero):  # pragma: no cover - compiled
    """Add Σd and Σd² of d = a − lut[prev_codes] over the first ``w`` columns to sums[0],
    sums[1]: the previous row looked up here instead of into a buffer first (one pass over
    the row less: measured 0.29 against 0.36 ms per 720p frame). The sums are formed in the
    type of ``zero``: float32 for the P.910 domain (``a`` and ``lut`` float32; vectorised, 16
    lanes in a 512-bit register), else float64; each added to the float64 ``sums``."""
    s = zero
    ss = zero
    for j in range(w):
        d = a[j] - lut[prev_codes[j]]
        s += d
        ss += d * d
    sums[0] += s
    sums[1] += ss


@kernel(fastmath=True, nogil=True)
def _abs_diff_row(a, b):  # pragma: no cover - compiled
    s = 0
    for j in range(a.shape[0]):
        d = np.int32(a[j]) - np.int32(b[j])
        s += d if d >= 0 else -d
    return s


@kernel(fastmath=True, nogil=True, error_model="numpy")
def _range_row(a, lo_hi):  # pragma: no cover - compiled
    """Lower lo_hi[0] to the row's smallest code and raise lo_hi[1] to its largest. The row's
    extremes are taken in its own type (min/max without a branch: a vectorised loop; widening
    each code to int64 first kept it scalar, 0.27 against 0.02 ms per 720p frame)."""
    lo = a[0]
    hi = a[0]
    for j in range(a.shape[0]):
        v = a[j]
        lo = min(lo, v)
        hi = max(hi, v)
    lo_hi[0] = min(lo_hi[0], np.int64(lo))
    lo_hi[1] = max(lo_hi[1], np.int64(hi))


@kernel(nogil=True)
def _aligned_rows(n, w):  # pragma: no cover - compiled
    """(n, ≥w) float64 rows that each start on a 64-byte boundary. The sums below are
    vectorised, and how a vectorised loop groups its additions can depend on where its
    arrays start: aligned buffers make a frame's sums the same bits wherever the frame
    itself lies in memory (a decoder's plane or a copy)."""
    wp = (w + 7) // 8 * 8
    buf = np.empty(n * wp + 8)
    off = ((64 - buf.ctypes.data % 64) % 64) // 8
    return buf[off : off + n * wp].reshape((n, wp))  # C-contiguous: columns w.. are spare


@kernel(nogil=True)
def _aligned_rows32(n, w):  # pragma: no cover - compiled
    """:func:`_aligned_rows` in float32 (the P.910 domain's rows)."""
    wp = (w + 15) // 16 * 16
    buf = np.empty(n * wp + 16, dtype=np.float32)
    off = ((64 - buf.ctypes.data % 64) % 64) // 4
    return buf[off : off + n * wp].reshape((n, wp))


@kernel(nogil=True)
def frame_sums(y, prev, lut_a, lut_b, have_prev):  # pragma: no cover - compiled
    """One pass over luma ``y`` (H, W) uint8/uint16 and the previous frame ``prev``:
    (10,) float64 = Σm, Σm² of the interior Sobel magnitude and Σd, Σd² of the frame
    difference in the domains of ``lut_a`` and ``lut_b``, then Σ|y − prev| and the interior
    pixel count (:func:`chosen_sums` with both domains)."""
    return chosen_sums(y, prev, lut_a, lut_b, have_prev, True, True)[:10]


@kernel(nogil=True)
def chosen_sums(
    y, prev, lut_a, lut_b, have_prev, want_a, want_b, want_range=False
):  # pragma: no cover
    """:func:`frame_sums` for the chosen domains only (``want_a``, ``want_b``; the sums of a
    domain not wanted stay 0): one variant of SI/TI costs half of both; (12,) float64, the
    last two the smallest and largest code of ``y`` where ``want_range`` (else 0; the same
    pass instead of two reductions over the frame). Rows are looked up
    into three-row buffers that stay in the L1 cache: cheaper than keeping the previous
    frame's values (measured: 3.3 against 6.7 ms at 720p). A domain's sums are the same bits
    whether the other is computed or not (each has its own buffers and accumulators)."""
    h, w = y.shape
    out = np.zeros(12)
    lo_hi = np.array([np.int64(2**62), np.int64(-1)])
    rows_a = _aligned_rows32(3, w)
    rows_b = _aligned_rows(3, w)
    sa = np.zeros(2)
    sb = np.zeros(2)
    ta = np.zeros(2)
    tb = np.zeros(2)
    mad = 0
    for i in range(h):
        k = i % 3
        if want_a:
            _map_row(y[i], lut_a, rows_a[k])
        if want_b:
            _map_row(y[i], lut_b, rows_b[k])
        if have_prev:
            if want_a:
                _diff_row(rows_a[k], prev[i], lut_a, w, ta, _F32(0))
            if want_b:
                _diff_row(rows_b[k], prev[i], lut_b, w, tb, 0.0)
            mad += _abs_diff_row(y[i], prev[i])
        if want_range:
            _range_row(y[i], lo_hi)
        if i >= 2:
            r0, r1, r2 = (i - 2) % 3, (i - 1) % 3, k
            if want_a:
                _sobel_row32(rows_a[r0], rows_a[r1], rows_a[r2], w, sa)
            if want_b:
                _sobel_row(rows_b[r0], rows_b[r1], rows_b[r2], w, sb)
    out[0], out[1], out[2], out[3] = sa[0], sa[1], ta[0], ta[1]
    out[4], out[5], out[6], out[7] = sb[0], sb[1], tb[0], tb[1]
    out[8] = mad
    out[9] = (h - 2) * (w - 2)
    if want_range:
        out[10], out[11] = lo_hi[0], lo_hi[1]
    return out
