"""The estimators as they were before the fits went block by block (commit 251d444): the oracle
of tests/acquisition/test_estimation_blocked.py.

This dense implementation materialises every N x K design matrix (and N x lags correlation) at
once; it is simple and was validated against the Cramer-Rao bound, so the bounded-memory one must
give its results to rounding.  Frozen copies, never imported by the package; only the modules the
fits need (``_checks``, ``_lsq``, ``_outliers``, ``sinefit``, ``covariance``)."""
