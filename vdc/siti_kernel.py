"""The native metrics' compiled kernel (``vdc.frame_metrics``): one pass over a frame's luma
and the previous frame's for P.910 SI and TI (float32), the legacy SI and TI (float64), the
MAFD and the range scan, each domain's sums apart so that one variant costs half of both.

The P.910 domain computes in float32 (its table, the Sobel, its square root, each column's
sums over a block of :data:`BLOCK_ROWS` rows; the blocks and the columns added in float64),
3-6e-9 relative from siti-tools' float64 on real frames (``benchmarks/bench_siti_kernel.py``),
far inside the three decimals siti-tools prints.

**The same bits from every compilation.** The sums are grouped in the source, not by the
compiler: each column is summed down the rows (an element-wise update of a row of column
sums, which vectorises as it stands), the columns then one after another, with no fast-math
reassociation, contraction or approximate functions anywhere a float is summed. With
``fastmath`` a reduction's grouping was the optimiser's choice: it differed between the copy
of a row kernel compiled on its own and the copy inlined into :func:`chosen_sums`, and Numba
links either (both are the same symbol), so a frame's TI depended on whether the process had
compiled the kernel or loaded it from the cache, on the order it met the argument types, and
on the frame's layout (a decoder's padded plane or a contiguous array): 1 run in 4 of an
end-to-end test gave another TI (``tests/vdc/test_kernel_bits.py``). Now the bits depend only
on the frames' values, whatever the layout, alignment, thread or cache state.
"""

from __future__ import annotations

import math

import numpy as np

from avdm.jit import kernel

_F32 = np.float32

# rows whose float32 column sums are added to the float64 ones at a time (P.910): 64 rows of
# values of at most a few thousand keep each float32 sum within about 1e-6 relative, and the
# frame's SI and TI within 1e-8 of float64 sums (measured at 720p, 1080p and 4K)
BLOCK_ROWS = 64


@kernel(fastmath=True, nogil=True)
def _map_row(codes, lut, out):  # pragma: no cover - compiled
    """out[j] = lut[codes[j]] (no arithmetic: fast-math changes no bit here)."""
    for j in range(codes.shape[0]):
        out[j] = lut[codes[j]]


@kernel(nogil=True)
def _sobel_cols32(r0, r1, r2, w, cs, css):  # pragma: no cover - compiled
    """Add the interior Sobel magnitude m of the middle of three float32 rows (its first ``w``
    columns) to the column sums cs (Σm) and css (Σm²), in float32: element by element, so
    the order of the additions is the rows' order whatever the compiler vectorises."""
    two = _F32(2)
    for j in range(1, w - 1):
        gx = (r0[j + 1] + two * r1[j + 1] + r2[j + 1]) - (r0[j - 1] + two * r1[j - 1] + r2[j - 1])
        gy = (r2[j - 1] + two * r2[j] + r2[j + 1]) - (r0[j - 1] + two * r0[j] + r0[j + 1])
        x = gx * gx + gy * gy
        cs[j] += math.sqrt(x)
        css[j] += x


@kernel(nogil=True)
def _sobel_cols(r0, r1, r2, w, cs, css):  # pragma: no cover - compiled
    """:func:`_sobel_cols32` on float64 rows in float64 (the legacy domain)."""
    for j in range(1, w - 1):
        gx = (r0[j + 1] + 2.0 * r1[j + 1] + r2[j + 1]) - (r0[j - 1] + 2.0 * r1[j - 1] + r2[j - 1])
        gy = (r2[j - 1] + 2.0 * r2[j] + r2[j + 1]) - (r0[j - 1] + 2.0 * r0[j] + r0[j + 1])
        x = gx * gx + gy * gy
        cs[j] += math.sqrt(x)
        css[j] += x


@kernel(nogil=True)
def _diff_cols(a, b, w, cs, css):  # pragma: no cover - compiled
    """Add d = a − b and d² over the first ``w`` columns to the column sums cs, css (in the
    rows' own type: float32 for P.910, float64 for the legacy domain)."""
    for j in range(w):
        d = a[j] - b[j]
        cs[j] += d
        css[j] += d * d


@kernel(nogil=True)
def _flush(cols32, cols64):  # pragma: no cover - compiled
    """Add the float32 column sums of a block of rows to the float64 ones, and clear them."""
    for q in range(cols32.shape[0]):
        for j in range(cols64.shape[1]):
            cols64[q, j] += np.float64(cols32[q, j])
            cols32[q, j] = 0


@kernel(nogil=True)
def _column_total(cols):  # pragma: no cover - compiled
    """Σ of a row of float64 column sums, left to right (one fixed order)."""
    s = 0.0
    for j in range(cols.shape[0]):
        s += cols[j]
    return s


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
    """(n, ≥w) float64 rows, zeroed, that each start on a 64-byte boundary (whole vectors:
    speed only, the sums' bits do not depend on where a row lies)."""
    wp = (w + 7) // 8 * 8
    buf = np.zeros(n * wp + 8)
    off = ((64 - buf.ctypes.data % 64) % 64) // 8
    return buf[off : off + n * wp].reshape((n, wp))  # C-contiguous: columns w.. are spare


@kernel(nogil=True)
def _aligned_rows32(n, w):  # pragma: no cover - compiled
    """:func:`_aligned_rows` in float32 (the P.910 domain's rows)."""
    wp = (w + 15) // 16 * 16
    buf = np.zeros(n * wp + 16, dtype=np.float32)
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
    pass instead of two reductions over the frame). Rows are looked up into three-row
    buffers that stay in the L1 cache (the previous frame's row into one more): cheaper than
    keeping the previous frame's values. Each quantity is summed per column, then over the
    columns in order (module docstring): the same bits for the same values, whatever the
    arrays' layout and however the kernel was compiled. A domain's sums are the same bits
    whether the other is computed or not (each has its own buffers)."""
    h, w = y.shape
    out = np.zeros(12)
    lo_hi = np.array([np.int64(2**62), np.int64(-1)])
    rows_a = _aligned_rows32(4, w)  # three rows for the Sobel, the last the previous frame's
    rows_b = _aligned_rows(4, w)
    block_a = _aligned_rows32(4, w)  # Σm, Σm², Σd, Σd² per column over the block's rows
    cols_a = _aligned_rows(4, w)  # the same over the blocks so far, float64
    cols_b = _aligned_rows(4, w)
    mad = 0
    for i in range(h):
        k = i % 3
        if want_a:
            _map_row(y[i], lut_a, rows_a[k])
        if want_b:
            _map_row(y[i], lut_b, rows_b[k])
        if have_prev:
            if want_a:
                _map_row(prev[i], lut_a, rows_a[3])
                _diff_cols(rows_a[k], rows_a[3], w, block_a[2], block_a[3])
            if want_b:
                _map_row(prev[i], lut_b, rows_b[3])
                _diff_cols(rows_b[k], rows_b[3], w, cols_b[2], cols_b[3])
            mad += _abs_diff_row(y[i], prev[i])
        if want_range:
            _range_row(y[i], lo_hi)
        if i >= 2:
            r0, r1, r2 = (i - 2) % 3, (i - 1) % 3, k
            if want_a:
                _sobel_cols32(rows_a[r0], rows_a[r1], rows_a[r2], w, block_a[0], block_a[1])
            if want_b:
                _sobel_cols(rows_b[r0], rows_b[r1], rows_b[r2], w, cols_b[0], cols_b[1])
        if want_a and (i % BLOCK_ROWS == BLOCK_ROWS - 1 or i == h - 1):
            _flush(block_a[:, :w], cols_a[:, :w])
    for q in range(4):
        out[q] = _column_total(cols_a[q, :w])
        out[4 + q] = _column_total(cols_b[q, :w])
    out[8] = mad
    out[9] = (h - 2) * (w - 2)
    if want_range:
        out[10], out[11] = lo_hi[0], lo_hi[1]
    return out
