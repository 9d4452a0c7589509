"""Delay and phase estimators for two channels excited by one sine (offline, on arrays).

- :func:`phase_delay` — delay of y behind x from a joint least-squares sine fit (IEEE Std
  1057/1241, frequency estimated); reaches the Cramer-Rao bound.  :func:`delay_between` reads
  the same delay off two fits already made at one frequency.
- :func:`sine_fit` — the single-channel fit: DC + chosen harmonics, three- or four-parameter.
  Both fits leave gross outliers out (``outlier_sigmas``, default :data:`OUTLIER_SIGMAS` robust
  standard deviations off the fit) and say which (``excluded``); :func:`find_outliers` finds those
  of several channels of one recording in one joint fit.
- :func:`covariance_delay` — the paper's Eq. 3: lag of the covariance maximum, one-sample
  resolution; the reference the fit is compared with.
- :func:`phase_difference_crlb`, :func:`delay_crlb`, :func:`sine_snr` — the bounds.

Every function checks its arguments first and raises ``ValueError`` naming the parameter.  Code
that works on a recording wraps its calls in :func:`estimation_errors` to turn those into
:class:`~hystbench.errors.EstimationError` naming the recording.  Positive delays: y lags x.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from hystbench.errors import EstimationError

from .covariance import CovarianceDelay, covariance_delay
from .crlb import delay_crlb, phase_difference_crlb, sine_snr
from .sinefit import (OUTLIER_SIGMAS, Harmonic, PhaseDelay, SineFit, delay_between, find_outliers, gross_outliers,
                      phase_delay, sine_fit)

__all__ = [
    "sine_fit",
    "phase_delay",
    "delay_between",
    "find_outliers",
    "gross_outliers",
    "covariance_delay",
    "phase_difference_crlb",
    "delay_crlb",
    "sine_snr",
    "estimation_errors",
    "OUTLIER_SIGMAS",
    "SineFit",
    "Harmonic",
    "PhaseDelay",
    "CovarianceDelay",
]


@contextmanager
def estimation_errors(recording: str) -> Iterator[None]:
    """Re-raise an estimator's ``ValueError`` as ``EstimationError`` naming ``recording``.

    >>> import numpy as np
    >>> with estimation_errors("run_0042.csv"):
    ...     sine_fit(np.zeros(100), 1000.0, 50.0)
    Traceback (most recent call last):
    ...
    hystbench.errors.EstimationError: run_0042.csv: x is flat (zero variance): it carries no phase
    """
    try:
        yield
    except EstimationError:
        raise
    except ValueError as err:
        raise EstimationError(f"{recording}: {err}") from err
