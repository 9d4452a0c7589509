"""Compiled median and median absolute deviation of one row (private; see :mod:`._outliers`).

The outlier screen takes a median and a MAD of every channel of a live window twice (the raw
samples, then the first fit's residuals): twelve ``np.median`` calls a window, a fifth of the
estimation stage's time on 25 000-sample windows, and on short windows mostly median's Python
wrapping.  This kernel takes both in one call (on its own copies), with the largest deviation
(free in that pass): Floyd and Rivest's selection for the upper middle, the lower middle of an
even count as the largest value below it, then the same on the absolute deviations.

Order statistics are exact, so the numbers are numpy's (:func:`numpy.median`) bit for bit,
whatever the order of the work; the mean of the two middles is ``(a + b) / 2``, numpy's own
operations.  A row holding a NaN gives NaN, as numpy does.  A selection that has not narrowed
after ``MAX_ROUNDS`` partitions (an adversarial order) sorts what is left: the worst case stays
O(n log n).
"""

from __future__ import annotations

import math

import numpy as np

from hystbench.jit import njit

MAX_ROUNDS = 256  # partitions before the rest is sorted (a row of 1e6 samples needs ~20)
SAMPLED = 600  # a range longer than this is narrowed by a selection in a sample of it first
DEPTH = 16  # levels of that narrowing at most (n, ~n^(2/3), ...: 1e12 samples need 5)


@njit(cache=True, nogil=True)
def _select(a: np.ndarray, k: int) -> float:
    """Reorder ``a`` (no NaN) so that ``a[k]`` is its k-th smallest value, nothing larger before
    it and nothing smaller after it; return that value.

    Floyd and Rivest's selection (CACM 18, 1975): a range of more than ``SAMPLED`` values is
    first narrowed by selecting k within a subrange around where the k-th value should be (about
    n^(2/3) values: the same selection, one level down), so the partition's pivot ``a[k]`` lands
    close to it (~1.5 n comparisons, a quickselect's ~3.4 n).  The partition is Hoare's: its scans
    stop at values equal to the pivot, so runs of equal values (a quantised channel) split
    evenly.  The levels are an explicit stack, not recursion (numba's cache does not keep
    recursive functions: a cached recursive kernel crashed the process on its next load)."""
    lo = np.empty(DEPTH, dtype=np.int64)  # the range of each level, outermost first
    hi = np.empty(DEPTH, dtype=np.int64)
    narrowed = np.zeros(DEPTH, dtype=np.bool_)  # its subrange's selection done: partition it now
    lo[0], hi[0] = 0, a.size - 1
    d = 0
    rounds = 0
    while d >= 0:
        left, right = lo[d], hi[d]
        if right <= left:
            d -= 1
            continue
        if rounds == MAX_ROUNDS:  # an adversarial order: sort what the outermost level has left
            a[lo[0]:hi[0] + 1].sort()
            break
        if right - left > SAMPLED and not narrowed[d] and d + 1 < DEPTH:
            narrowed[d] = True
            n = right - left + 1
            i = k - left + 1
            z = math.log(n)
            s = 0.5 * math.exp(2.0 * z / 3.0)
            sd = 0.5 * math.sqrt(z * s * (n - s) / n) * (-1.0 if i < n / 2 else 1.0)
            d += 1
            lo[d] = max(left, int(k - i * s / n + sd))
            hi[d] = min(right, int(k + (n - i) * s / n + sd))
            narrowed[d] = False
            continue
        rounds += 1
        t = a[k]  # Hoare's partition around it: scans stop at values equal to it, so ties split evenly
        i = left
        j = right
        while i <= j:
            while a[i] < t:
                i += 1
            while t < a[j]:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        # now a[left..j] <= t <= a[i..right], and everything between j and i equals t
        if k <= j:
            hi[d] = j
        elif k >= i:
            lo[d] = i
        else:
            hi[d] = lo[d]  # a[k] is in place
        narrowed[d] = False
    return a[k]


@njit(cache=True, nogil=True)
def _middle(a: np.ndarray) -> float:
    """The median of ``a`` (no NaN, size > 0), as numpy takes it, reordering ``a``."""
    n = a.size
    h = n // 2
    upper = _select(a, h)
    if n % 2:
        return upper
    lower = a[0]  # everything before a[h] is <= it: the lower middle is their largest
    for i in range(1, h):
        if a[i] > lower:
            lower = a[i]
    return (lower + upper) / 2.0


@njit(cache=True, nogil=True)
def median_mad(x: np.ndarray) -> tuple[float, float, float]:
    """(median, median absolute deviation, largest absolute deviation) of ``x`` (1-D float64, size
    > 0, left as it is); NaN for all three if ``x`` holds a NaN, and for the MAD and the largest
    if a deviation is NaN (infinite samples), as numpy gives.  The largest deviation lets a caller
    see that no sample is beyond k MADs without comparing every one: it is the largest of the
    very numbers numpy would compare.

    The deviations are taken from ``x``, in the record's order, not from the copy the first
    selection reordered: its halves and nested ranges give the second selection poor pivots
    (measured on a pass of the bench's windows: 44 ms against 46 ms, and 53 ms with a scattered
    copy; numpy's two medians 63 ms)."""
    n = x.size
    a = np.empty(n)
    for i in range(n):
        if math.isnan(x[i]):
            return math.nan, math.nan, math.nan
        a[i] = x[i]
    med = _middle(a)
    if not math.isfinite(med):  # infinite middle samples: one's deviation is inf - inf
        return med, math.nan, math.nan
    top = 0.0
    for i in range(n):
        d = abs(x[i] - med)
        a[i] = d
        top = max(top, d)
    return med, _middle(a), top


BINS = 256  # histogram bins of :func:`within_mads` over a row's range
_EPS = 2.0 ** -52


@njit(cache=True, nogil=True)
def within_mads(x: np.ndarray, k: float) -> bool:
    """True if no sample of ``x`` (1-D float64) can lie more than ``k`` MADs from the median, as
    :func:`median_mad` gives them (so a screen comparing each deviation with ``k`` times the MAD
    would flag none); False: unknown, take the median and MAD.  One histogram of the row instead
    of two selections (~4 ns a sample against ~16): most rows of a clean recording are settled by it.

    The proof, in units of a bin's width ``w`` (``BINS`` bins over [min, max]; a sample's computed
    bin is off its true one by at most one, rounding): (1) the median lies between the bins of the
    two middle order statistics, +-1, so every deviation is at most ``dev`` bins; (2) if no
    ``win + 3`` consecutive bins hold more than (n - 1) // 2 samples, fewer than half the samples
    lie within ``win / 2`` bins of any point, so the MAD (the mean of the two middle deviations,
    or the middle one) is at least ``win / 2`` bins.  ``dev <= k win / 2`` then settles it; the
    margins cover the roundings of the median, the deviations and ``k`` times the MAD (a few eps
    of the largest magnitude).  Not finite, flat, or too concentrated (quantised) rows: False."""
    n = x.size
    if n < 3:
        return False
    lo = x[0]
    hi = x[0]
    for i in range(n):
        v = x[i]
        if not (v >= lo):  # also a NaN
            if math.isnan(v):
                return False
            lo = v
        if v > hi:
            hi = v
    span = hi - lo
    if not (span > 0.0 and math.isfinite(span)):
        return False
    scale = BINS / span  # bins per signal unit
    if not math.isfinite(scale):  # a span of subnormals: the bins would be 0 * inf
        return False
    counts = np.zeros(BINS, dtype=np.int64)
    for i in range(n):
        b = int((x[i] - lo) * scale)
        counts[min(b, BINS - 1)] += 1
    m1, m2 = (n - 1) // 2, n // 2  # the middle order statistics (0-based)
    b1 = b2 = -1
    below = 0
    for b in range(BINS):
        below += counts[b]
        if b1 < 0 and below > m1:
            b1 = b
        if below > m2:
            b2 = b
            break
    slack = 8.0 * _EPS * max(abs(lo), abs(hi)) * scale  # roundings of the median and deviations, in bins
    dev = max(BINS - b1 + 1.0, b2 + 2.0) + 0.01 + slack  # every deviation from the median is within
    win = math.ceil(2.0 * dev / (k * (1.0 - 1e-9)) + 2.0 * slack)
    width = win + 3
    if width > BINS:
        return False
    inside = 0
    for b in range(width):
        inside += counts[b]
    most = inside
    for b in range(width, BINS):
        inside += counts[b] - counts[b - width]
        most = max(most, inside)
    return most <= m1
