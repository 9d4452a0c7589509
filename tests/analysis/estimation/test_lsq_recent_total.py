"""The thread's kept regressors (:func:`_lsq.bases`) are counted as they come and go (issue 14).

Before, every new frequency summed the floats of every kept :class:`_lsq.Bases` to decide what to
drop (a live window at 25 kS/s keeps ~37 of them: 2.6 % of the estimation stage).  The running
count must stay the sum an independent count over the kept ones gives, within the bound, and the
most recent regressors must still be found."""

from __future__ import annotations

import threading

import numpy as np

from hystbench.analysis.estimation import _lsq


def test_the_running_count_is_the_sum_of_what_is_kept():
    ks = np.array([1.0, 2.0, 3.0, 4.0])
    n, fs = 6250, 25_000.0
    errors: list[str] = []
    finished = threading.Event()

    def work() -> None:
        per = (1 + 2 * ks.size) * n  # floats of one record's regressors
        made = []
        for j in range(3 * _lsq.RECENT_FLOATS // per):  # three times what fits: many are dropped
            made.append(_lsq.bases(np.array([160.0 + 1e-3 * j]), ks, n, fs))
            kept = sum(b.floats for b in _lsq._recent.lru.values())
            if _lsq._recent.floats != kept or kept > _lsq.RECENT_FLOATS:
                errors.append(f"after {j + 1}: counted {_lsq._recent.floats}, kept {kept}")
                return
        if _lsq.bases(np.array([160.0 + 1e-3 * j]), ks, n, fs) is not made[-1]:
            errors.append("the latest regressors were not kept")
        if len(_lsq._recent.lru) != _lsq.RECENT_FLOATS // per:
            errors.append(f"{len(_lsq._recent.lru)} kept, {_lsq.RECENT_FLOATS // per} fit the bound")
        finished.set()

    t = threading.Thread(target=work)  # a fresh thread: nothing kept yet
    t.start()
    t.join(timeout=600)
    assert errors == []
    assert finished.is_set(), "the thread raised (see the warning above)"

