"""Helpers shared by the estimation tests."""

import threading


def in_fresh_thread(fn):
    """``fn()`` run in a new thread, whose kept regressors and recent-fit records start empty."""
    out: list = []
    t = threading.Thread(target=lambda: out.append(fn()))
    t.start()
    t.join(timeout=600)  # only a hang takes this long
    assert out, "the work in the fresh thread did not finish"
    return out[0]
