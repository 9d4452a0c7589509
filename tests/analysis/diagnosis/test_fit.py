"""The weighted least squares of a diagnosis (analysis/diagnosis/fit.py) against an independent solution:
priors as pseudo-observations, bounds, the covariance."""

from __future__ import annotations

import numpy as np
import pytest

from hystbench.analysis.diagnosis.fit import Column, solve


def test_solve_matches_the_normal_equations_with_priors():
    rng = np.random.default_rng(1)
    n = 200
    J = rng.normal(size=(n, 3))
    beta = np.array([0.5, -2.0, 1.5])
    sigma = rng.uniform(0.5, 2.0, n)
    y = J @ beta + sigma * rng.normal(size=n)
    cols = [Column("a", J[:, 0], prior=0.1), Column("b", J[:, 1]), Column("c", J[:, 2], prior=3.0)]
    sol = solve(y, sigma, cols)
    W = np.diag(1 / sigma ** 2)
    P = np.diag([1 / 0.1 ** 2, 0.0, 1 / 3.0 ** 2])
    info = J.T @ W @ J + P
    expected = np.linalg.solve(info, J.T @ W @ y)
    np.testing.assert_allclose(sol.beta, expected, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(sol.cov, np.linalg.inv(info), rtol=1e-6)
    resid = (y - J @ expected) / sigma
    assert sol.chi2 == pytest.approx(resid @ resid, rel=1e-9)
    assert sol.chi2_prior == pytest.approx(expected[0] ** 2 / 0.01 + expected[2] ** 2 / 9.0, rel=1e-9)


def test_a_lower_bound_holds_and_the_rest_refits():
    x = np.linspace(0, 1, 50)
    y = -1.0 * x + 2.0  # the best slope is negative: a bound at 0 must hold it there
    sol = solve(y, np.ones_like(x), [Column("slope", x, lower=0.0), Column("offset", np.ones_like(x))])
    assert sol.value("slope")[0] == pytest.approx(0.0, abs=1e-12)
    assert sol.value("offset")[0] == pytest.approx(np.mean(y), rel=1e-9)


def test_an_upper_bound_holds_and_the_rest_refits():
    """A relaxation's time constant is refined only within its grid's span: an upper bound on 1/tau."""
    x = np.linspace(0, 1, 50)
    y = 3.0 * x + 2.0  # the best slope is 3: a bound at 1 must hold it there, the offset takes the rest
    sol = solve(y, np.ones_like(x), [Column("slope", x, upper=1.0), Column("offset", np.ones_like(x))])
    assert sol.value("slope")[0] == pytest.approx(1.0, abs=1e-12)
    assert sol.value("offset")[0] == pytest.approx(np.mean(y - x), rel=1e-9)


def test_only_the_given_rows_are_fitted():
    x = np.arange(10.0)
    y = np.where(x < 5, 3.0 * x, 100.0)
    sol = solve(y, np.ones_like(x), [Column("k", x)], rows=np.arange(5))
    assert sol.value("k")[0] == pytest.approx(3.0, rel=1e-12)
    assert sol.fitted[9] == pytest.approx(27.0)  # the model everywhere, fitted on the rows


def test_a_column_inside_the_span_of_the_others_changes_nothing():
    """A refused suspect's generic term is its fitted change beside its own columns: a column exactly in
    their span.  The fit, and its chi2, must be that of the columns without it (numpy's lstsq on them,
    an independent computation).  Strongly correlated columns of sizes 1e-3 to 1e3, like a calibration's:
    the solver's rcond=-1 first solve lost 13 of chi2 to rounding here."""
    rng = np.random.default_rng(1)
    n, k = 1200, 150
    scale = np.logspace(-3, 3, k)
    X = rng.normal(size=(n, k)) * scale
    X[:, 1:] += 0.999 * X[:, :1] * scale[1:] / scale[0]
    d = 3.0 * rng.normal(size=n) + X[:, :5] @ rng.normal(size=5)
    columns = [Column(f"c{i}", X[:, i]) for i in range(k)]
    exact = float(np.sum((d - X @ np.linalg.lstsq(X, d, rcond=None)[0]) ** 2))
    inside = Column("generic.suspect", X[:, :10] @ rng.normal(size=10))
    for cols in (columns, columns + [inside], [inside] + columns):
        assert solve(d, np.ones(n), cols).chi2 == pytest.approx(exact, rel=1e-9)
    bounded = solve(d, np.ones(n), columns + [inside, Column("b", rng.normal(size=n), lower=0.0)])
    assert bounded.chi2 <= exact * (1 + 1e-9)


def test_a_column_or_a_row_the_simulator_could_not_compute_is_fitted_without():
    """A recording whose sidecar names another rig gave a replay with non-finite numbers, and the fit a
    traceback.  A column with a NaN on the rows is fitted without (coefficient 0) and a row whose
    residual is NaN says nothing: the fit is numpy's lstsq on what is left."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=(40, 2))
    y = x @ np.array([2.0, -1.0]) + 0.01 * rng.normal(size=40)
    broken = rng.normal(size=40)
    broken[7] = np.nan
    y_nan = y.copy()
    y_nan[11] = np.nan
    sol = solve(y_nan, np.ones(40), [Column("a", x[:, 0]), Column("b", x[:, 1]), Column("broken", broken)])
    keep = np.arange(40) != 11
    expected, *_ = np.linalg.lstsq(x[keep], y[keep], rcond=None)
    np.testing.assert_allclose(sol.beta[:2], expected, rtol=1e-9)
    assert sol.beta[2] == 0.0 and np.all(np.isfinite(sol.fitted)) and np.isfinite(sol.chi2)


def test_when_lapacks_svd_gives_up_the_covariance_comes_from_the_symmetric_solver(monkeypatch):
    """numpy's pinv raised "SVD did not converge" on a finite, ill-conditioned information matrix; the
    covariance is then the symmetric pseudo-inverse, the same matrix here (where the SVD would work)."""
    rng = np.random.default_rng(4)
    J = rng.normal(size=(60, 3))
    y = J @ np.array([1.0, 2.0, 3.0])
    cols = [Column(n, J[:, i]) for i, n in enumerate("abc")]
    expected = solve(y, np.ones(60), cols).cov
    pinv = np.linalg.pinv

    def svd_gives_up(a, *args, hermitian=False, **kw):
        if not hermitian:
            raise np.linalg.LinAlgError("SVD did not converge")
        return pinv(a, *args, hermitian=True, **kw)

    monkeypatch.setattr(np.linalg, "pinv", svd_gives_up)
    np.testing.assert_allclose(solve(y, np.ones(60), cols).cov, expected, rtol=1e-8)
