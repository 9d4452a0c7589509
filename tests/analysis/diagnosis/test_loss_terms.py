"""The generic loss terms (issue 28): a synthetic MagNet-like table with a known magnetic relaxation
(the i2GSE) or a known free Steinmetz term gets it back, named as not in the catalogue, its parameters
within their standard errors of the truth, the held-out error shrunk; a table of rate-independent loss
and classical eddy currents alone gets no generic term.  The truth is computed here from its formula
(closed-form shape integrals of MagNet's symmetric shapes), not with the code under test."""

from __future__ import annotations

import functools
import json
import math

import numpy as np
import pytest

from hystbench.analysis.diagnosis.loss_separation import diagnose_energy

K_H, BETA = 0.5, 2.6  # J/m^3 per cycle at 0.1 T (N87-like), and its B exponent
NOISE_LN = 0.02  # 2 % scatter, about MagNet's repeatability
SINE = (-1.0, -1.0, -1.0, -1.0)
#: sines, triangles (no flat time) and trapezoids whose B is flat between the ramps (duty_1 == duty_3)
SHAPES = [SINE, (0.5, 0.0, 0.5, 0.0), (0.2, 0.0, 0.8, 0.0), (0.4, 0.1, 0.4, 0.1), (0.3, 0.2, 0.3, 0.2),
          (0.2, 0.3, 0.2, 0.3), (0.1, 0.4, 0.1, 0.4)]


@functools.cache
def _sine_integral(p: float) -> float:
    """int_0^1 |d/dphi sin 2 pi phi|^p dphi, by quadrature (independent of the code's closed form)."""
    phi = (np.arange(200_000) + 0.5) / 200_000
    return float(np.mean(np.abs(2 * np.pi * np.cos(2 * np.pi * phi)) ** p))


def _shape_factor(d: tuple[float, ...], p: float) -> float:
    """S_p of a sine (1) or a symmetric MagNet shape: b swings 2 over duty_1 and back over duty_3."""
    if d == SINE:
        return 1.0
    return (d[0] * (2 / d[0]) ** p + d[2] * (2 / d[2]) ** p) / _sine_integral(p)


def table(seed: int, *, k_c: float = 0.0, steinmetz: tuple[float, float, float] | None = None,
          relax: tuple[float, float, float, float] | None = None,
          series: tuple[float, float, float, float] | None = None,
          falling: tuple[float, float, float] | None = None):
    """A grid of 16 frequencies 50-500 kHz x 6 flux densities 20-250 mT x SHAPES, W per cycle known:
    rate-independent K_H (B/0.1)^BETA, + k_c f B^2 S_2, + k_s (f/100 kHz)^g (B/0.1)^d S_(1+g), + per flat
    segment k_r (|dB/dt| / 1 T/us)^a_r (B/0.1)^b_r (1 - exp(-t_flat/tau)), + the rate series
    k_1 (f/100 kHz) (B/0.1)^d_1 S_2 + k_2 (f/100 kHz)^2 (B/0.1)^d_2 S_3, + a loss falling with f,
    k_f (f/100 kHz)^-g_f (B/0.1)^d_f (every shape alike)."""
    rng = np.random.default_rng(seed)
    f0 = np.arange(50e3, 501e3, 30e3)
    grid = [(f, b, d) for f in f0 for b in np.geomspace(0.02, 0.25, 8) for d in SHAPES]
    f = np.array([g[0] for g in grid])
    b = np.array([g[1] for g in grid]) * np.exp(rng.uniform(-0.05, 0.05, len(grid)))
    duty = np.array([g[2] for g in grid])
    w = K_H * (b / 0.1) ** BETA
    s2 = np.array([_shape_factor(tuple(d), 2.0) for d in duty])
    w = w + k_c * f * b**2 * s2
    if steinmetz is not None:
        k_s, g, dl = steinmetz
        sp = np.array([_shape_factor(tuple(d), 1.0 + g) for d in duty])
        w = w + k_s * (f / 1e5) ** g * (b / 0.1) ** dl * sp
    if series is not None:
        k_1, d_1, k_2, d_2 = series
        s3 = np.array([_shape_factor(tuple(d), 3.0) for d in duty])
        w = w + k_1 * (f / 1e5) * (b / 0.1) ** d_1 * s2 + k_2 * (f / 1e5) ** 2 * (b / 0.1) ** d_2 * s3
    if falling is not None:
        k_f, g_f, d_f = falling
        w = w + k_f * (f / 1e5) ** -g_f * (b / 0.1) ** d_f
    if relax is not None:
        k_r, a_r, b_r, tau = relax
        flat = duty[:, 1] > 0
        rate = 2 * b * f / np.where(flat, duty[:, 0], 1.0)  # T/s over the ramp before each flat
        t_flat = duty[:, 1] / f
        per = k_r * (rate / 1e6) ** a_r * (b / 0.1) ** b_r * (1 - np.exp(-t_flat / tau))
        w = w + np.where(flat, 2 * per, 0.0)  # two flats a period
    return f, b, w * np.exp(rng.normal(0.0, NOISE_LN, f.size)), duty


def _within(est: dict, truth: float, sigmas: float = 3.0) -> bool:
    return abs(est["value"] - truth) <= sigmas * est["std"]


RELAX = (1.5, 1.0, 2.0, 2e-6)  # k_r J/m^3 a transition at 1 T/us, 0.2 T pp; alpha_r; beta_r; tau 2 us


def test_relaxation_is_recovered_where_flat_segments_are_calibrated_on():
    f, b, w, duty = table(1, k_c=1e-4, relax=RELAX)
    r = diagnose_energy(f, b, w, duty=duty, calibrate_on="all_shapes")
    assert sorted(r["effects"]) == ["flat_segment_relaxation", "lamination_eddy_currents"]
    assert r["not_in_catalogue"] == ["flat_segment_relaxation"]
    assert any("flat_segment_relaxation (not in the catalogue:" in s for s in r["reported"])
    p = r["parameters"]["flat_segment_relaxation"]
    for key, truth in zip(("k_r_J_per_m3_per_transition", "alpha_r", "beta_r", "tau_s"), RELAX):
        assert _within(p[key], truth), (key, p[key], truth)
    assert _within(r["parameters"]["lamination_eddy_currents"]["k_c_J_s_per_m3_T2"], 1e-4)
    assert r["improvement"] > 5 and r["residual_after"] < 1.5  # held out to the noise
    assert r["shapes"]["groups"]["trapezoid"]["improvement"] > 5
    json.dumps(r, allow_nan=False)


def test_relaxation_is_said_unidentifiable_from_sines_and_triangles_not_forced():
    """The default calibration (sines and symmetric triangles) has no flat segment: the relaxation is
    not fitted there, and the report says why, instead of naming something else for it."""
    f, b, w, duty = table(1, k_c=1e-4, relax=RELAX)
    r = diagnose_energy(f, b, w, duty=duty)
    assert "flat_segment_relaxation" in r["not_identifiable"] and "flat_segment_relaxation" not in r["effects"]
    assert "relaxation not identifiable" in r["verdict"]


@pytest.mark.parametrize("seed", [1, 2])
def test_free_steinmetz_term_is_recovered_and_not_given_a_catalogue_name(seed: int):
    """Calibrated across the band (``interleaved``): there a single power law and the rate series differ,
    and the free exponent, the truth, is named (on 50-170 kHz alone they are near look-alikes: seeds 1
    and 2 (these) get it there too, 11.6x and 19.3x held out, seed 3 the series, 2.2x;
    docs/diagnosis.md, "The rate series")."""
    truth = (0.2, 0.6, 2.3)  # k_s J/m^3 at 100 kHz, 0.1 T (a sine); gamma (alpha = 1.6); delta
    f, b, w, duty = table(seed, steinmetz=truth)
    r = diagnose_energy(f, b, w, duty=duty, split="interleaved")
    assert r["effects"] == ["steinmetz_rate_dependence"] and r["effect"] is None
    assert "not in the catalogue" in r["verdict"]
    p = r["parameters"]["steinmetz_rate_dependence"]
    assert _within(p["k_s_J_per_m3_at_100kHz_0.1T"], truth[0])
    assert _within(p["alpha"], 1 + truth[1]) and _within(p["delta"], truth[2])
    # held out at every third frequency, with the exponents as fitted: within 2.5 noise floors
    assert r["improvement"] > 5 and r["residual_after"] < 2.5
    assert r["steps"][-1]["terms"] == ["steinmetz_rate_dependence"]


def test_a_large_off_grid_table_is_fitted_to_its_least_squares_optimum():
    """20 000 rows of a Steinmetz law (P = k f^1.5 B^2.7, 2 % scatter) at random frequencies and flux
    densities, as a pooled datasheet or a big measurement campaign gives: the free term's exponents
    within three standard errors of the law's, and the fit's sum of squares at or below the law's own.
    An iterative trust-region step (LSMR, once used above 3000 rows for speed) stopped early there:
    alpha 1.5072 +- 0.0015, five standard errors off (on 50 000 rows 1.5066 +- 0.0009, seven)."""
    from hystbench.analysis.diagnosis.loss_separation import fit_terms
    from hystbench.analysis.diagnosis.loss_terms import STEINMETZ

    rng = np.random.default_rng(7)
    n = 20_000
    f = np.exp(rng.uniform(math.log(5e4), math.log(5e5), n))
    b = np.exp(rng.uniform(math.log(0.01), math.log(0.3), n))
    truth = (f / 1e5) ** 0.5 * (b / 0.1) ** 2.7  # J/m^3 per cycle: 1 at 100 kHz and 0.1 T
    w = truth * np.exp(rng.normal(0.0, 0.02, n))
    fit = fit_terms(f, b, w, (STEINMETZ,))
    p = fit.parameters()[STEINMETZ.name]
    assert abs(p["alpha"][0] - 1.5) <= 3 * p["alpha"][1] and abs(p["delta"][0] - 2.7) <= 3 * p["delta"][1], p
    assert fit.rss <= float(np.sum(np.log(w / truth) ** 2))


def test_a_steinmetz_law_on_the_prescribed_split_replaces_the_series_taken_before_it(tmp_path, capsys):
    """A sine table of a plain Steinmetz law (P = k f^1.5 B^2.7: 46 frequencies x 20 flux densities,
    2 % scatter), calibrated at 50-190 kHz: the tiers take the rate series first, and on top of it the
    free term fails the inner extrapolation (its window ranks look-alikes by chance).  In its place the
    law is decisively better, its exponents interior: it replaces the series, with the law's exponents,
    and predicts the held-out rows to the noise (a hostile probe's table: 0.097 log10 with the series)."""
    rng = np.random.default_rng(1)  # the probe's table, drawn as it drew it
    rows = []
    for fk in np.round(np.geomspace(5e4, 5e5, 46), -2):
        for bk in np.geomspace(0.01, 0.3, 20) * np.exp(rng.normal(0.0, 0.05, 20)):
            bk = round(float(bk), 5)
            rows.append((fk, bk, (fk / 1e5) ** 0.5 * (bk / 0.1) ** 2.7 * math.exp(rng.normal(0.0, 0.02))))
    f, b, w = (np.array(c) for c in zip(*rows))
    r = diagnose_energy(f, b, w, split="low_third")
    assert r["effects"] == ["steinmetz_rate_dependence"], r["verdict"]
    assert "rate_series replaced by steinmetz_rate_dependence" in r["verdict"]
    p = r["parameters"]["steinmetz_rate_dependence"]
    assert _within(p["alpha"], 1.5) and _within(p["delta"], 2.7)
    assert r["improvement"] > 10 and r["residual_after"] < 1.5
    # the module's own command line prints the replacement (it raised KeyError there)
    from pathlib import Path

    from hystbench.analysis.diagnosis.loss_separation import main

    real = Path(__file__).resolve().parents[2] / "data" / "real" / "magnet_N87_sine.json"
    (tmp_path / "law.json").write_text(json.dumps({**json.loads(real.read_text()), "material": "LAW"}))
    (tmp_path / "law.csv").write_text("frequency_Hz,flux_density_peak_T,loss_W_per_m3\n" + "".join(
        f"{float(fk)!r},{float(bk)!r},{float(wk * fk)!r}\n" for fk, bk, wk in zip(f, b, w)))
    assert main([str(tmp_path / "law.csv")]) == 0
    assert "replaced rate_series by steinmetz_rate_dependence" in capsys.readouterr().out


SERIES_TRUTH = (0.05, 2.6, 0.05, 2.9)  # k_1, delta_1, k_2 (J/m^3 at 100 kHz, 0.1 T, a sine), delta_2


@pytest.mark.parametrize("seed", [1, 2])
def test_a_rate_series_is_recovered_and_extrapolates_where_a_free_exponent_would_not(seed: int):
    """A dynamic field H = a_1(B) dB/dt + a_2(B) dB/dt |dB/dt| (energy per cycle growing as f and f^2 at
    once): fitted on 50-170 kHz and held out to 500 kHz, the series is named (not in the catalogue) with
    its four parameters and predicts every shape within a few noise floors (a single power law in f
    cannot follow a curve whose log slope grows with f)."""
    f, b, w, duty = table(seed, series=SERIES_TRUTH)
    r = diagnose_energy(f, b, w, duty=duty)
    assert r["effects"] == ["rate_series"] and r["not_in_catalogue"] == ["rate_series"]
    assert any("rate_series (not in the catalogue:" in s for s in r["reported"])
    p = r["parameters"]["rate_series"]
    for key, truth in zip(("k_1_J_per_m3_at_100kHz_0.1T", "delta_1", "k_2_J_per_m3_at_100kHz_0.1T", "delta_2"), SERIES_TRUTH):
        assert _within(p[key], truth), (key, p[key], truth)
    assert r["improvement"] > 5 and r["residual_after"] < 6  # measured 4.3 and 3.2 noise floors


@pytest.mark.parametrize("calibrate_on", ["sine_triangle", "all_shapes"])
def test_rate_independent_plus_classical_gets_no_generic_term(calibrate_on: str):
    f, b, w, duty = table(3, k_c=1e-4)
    r = diagnose_energy(f, b, w, duty=duty, calibrate_on=calibrate_on)
    assert r["effects"] == ["lamination_eddy_currents"] and r["not_in_catalogue"] == []
    assert not r["beyond_catalogue"]["needed"]
    assert r["residual_after"] < 1.5


@pytest.mark.parametrize("duty", [(0.2, 0.0, 0.8, 0.0), (0.1, 0.4, 0.1, 0.4), (0.3, 0.2, 0.3, 0.2)])
def test_a_sampled_waveform_has_the_shape_factor_of_its_duties(duty: tuple[float, ...]):
    """The measured-B(t) path (rows of samples) gives the closed form's S_p on MagNet's own waveform,
    rebuilt by formats.flux_shapes and sampled 1024 times; and a sampled sine gives 1."""
    from hystbench.analysis.diagnosis.loss_terms import Rows
    from hystbench.formats.flux_shapes import shape_flux_density

    phase = np.arange(1024) / 1024
    wave = np.stack([shape_flux_density(duty, 1.0, phase), np.sin(2 * np.pi * phase)])
    rows = Rows(np.array([1e5, 1e5]), np.array([0.1, 0.1]), waveform=wave)
    for p in (1.5, 2.0, 2.6):
        s = np.exp(rows.ln_shape_factor(p))
        assert s[0] == pytest.approx(_shape_factor(duty, p), rel=0.01)  # symmetric shapes: the closed form here
        assert s[1] == pytest.approx(1.0, rel=1e-3)


def test_a_terms_size_is_its_energy_at_the_reference_point_by_the_delta_method():
    """The size rule's standard error (a term is taken only when its energy at 100 kHz, 0.1 T is
    fitted beyond two standard errors) equals the delta method done here by finite differences."""
    from hystbench.analysis.diagnosis.loss_separation import _scale_rel_std, fit_terms
    from hystbench.analysis.diagnosis.loss_terms import SERIES, STEINMETZ, Rows, n_params, term_part

    f, b, w, duty = table(1, series=SERIES_TRUTH)
    ref = Rows(np.array([1e5]), np.array([0.1]))
    for term in (SERIES, STEINMETZ):
        fit = fit_terms(f, b, w, (term,), duty)
        i = 3
        x = fit.x[i:i + n_params(term)]
        grad = np.array([(term_part(term, x + h, ref)[0] - term_part(term, x - h, ref)[0]) / 2e-6
                         for h in np.eye(x.size) * 1e-6])
        cov = fit.cov[i:i + x.size, i:i + x.size]
        assert _scale_rel_std(fit) == pytest.approx(math.sqrt(grad @ cov @ grad), rel=1e-4)


def test_the_fits_jacobian_is_the_derivative_of_the_model_for_every_term_and_waveform():
    """The fits take their Jacobian in closed form (speed); here it is checked against scipy's central
    differences of the model itself, every library term at once, on sines, MagNet's shapes (asymmetric
    triangles, trapezoids whose B drifts between the ramps) and sampled B(t), temperatures varying."""
    from scipy.optimize import approx_fprime

    from hystbench.analysis.diagnosis.loss_separation import log_energy, log_energy_jacobian
    from hystbench.analysis.diagnosis.loss_terms import LIBRARY, Rows, n_params

    rng = np.random.default_rng(7)
    duty = np.array(SHAPES + [(0.1, 0.0, 0.9, 0.0), (0.6, 0.1, 0.2, 0.1)] * 3)
    n = len(duty)
    f, b = rng.uniform(50e3, 500e3, n), rng.uniform(0.02, 0.3, n)
    phase = np.arange(1024) / 1024
    wave = np.sin(2 * np.pi * phase)[None, :] + rng.uniform(0.0, 0.3, (n, 1)) * np.sin(6 * np.pi * phase)[None, :]
    wave /= np.max(np.abs(wave), axis=1, keepdims=True)
    x = np.concatenate([[math.log(0.5), 2.6, 0.1]] + [rng.uniform(0.5, 1.5, n_params(t)) for t in LIBRARY])
    i = 3
    for t in LIBRARY:  # each term at a point inside its bounds: ln scales, exponents, ln tau, temperature
        k = n_params(t)
        x[i] = math.log(0.05) if t.kind != "temperature" else 0.004
        if t.kind == "relaxation":
            x[i + 3] = math.log(3e-6)
        if t.kind == "temperature":
            x[i + 1] = -2e-5
        i += k
    for rows in (Rows(f, b, duty, rng.uniform(25, 90, n)), Rows(f, b), Rows(f, b, None, None, wave)):
        exact = log_energy_jacobian(x, LIBRARY, rows)
        numeric = np.array([approx_fprime(x, lambda v, r=r: log_energy(v, LIBRARY, rows)[r], 1e-7) for r in range(n)])
        assert np.all(np.isfinite(exact))
        np.testing.assert_allclose(exact, numeric, rtol=1e-4, atol=1e-6)


FALLING_TRUTH = (0.1, 1.5, 2.0)  # k_f J/m^3 at 100 kHz, 0.1 T; gamma; delta: N87's sines fit 0.05-0.07, 1.6, 1.9-2.0


@pytest.mark.parametrize("seed", [1, 2])
def test_a_loss_falling_with_frequency_is_recovered_beside_the_rate_series(seed: int):
    """A loss per cycle that falls with f (the tail of a relaxation peak below the band), beside the rate
    series, calibrated on 50-170 kHz: no rate term can fall, so the falling term is taken, named as not in
    the catalogue, its exponents within their errors of the truth, and the rows to 500 kHz are predicted
    within a few noise floors, as the series alone is (its first order is not resolved by the window)."""
    f, b, w, duty = table(seed, series=SERIES_TRUTH, falling=FALLING_TRUTH)
    r = diagnose_energy(f, b, w, duty=duty)
    assert "falling_rate_dependence" in r["effects"] and "falling_rate_dependence" in r["not_in_catalogue"]
    p = r["parameters"]["falling_rate_dependence"]
    for key, truth in zip(("k_f_J_per_m3_at_100kHz_0.1T", "gamma", "delta"), FALLING_TRUTH):
        assert _within(p[key], truth), (key, p[key], truth)
    assert r["improvement"] > 5 and r["residual_after"] < 6  # measured 16.3x, 3.3 and 10.1x, 5.5 noise floors


def test_a_term_fitted_to_nothing_reports_no_standard_error_and_a_real_one_does():
    """On a table without a falling loss, the falling term fitted alone sits at its floor (1e-9 J/m^3
    at the reference point, eight decades below the loss): the pseudo-inverse of J'J cut off its
    directions and reported k_f = 1.65e-09 +- 5.7e-21, certainty where the rows say nothing.  Its
    parameters are now said not determined (JSON null); a series that is in the table keeps its
    errors, and the truth is within three of them."""
    from hystbench.analysis.diagnosis.loss_separation import _param_json, fit_terms
    from hystbench.analysis.diagnosis.loss_terms import FALLING, SERIES, form

    f, b, w, duty = table(1)
    nothing = fit_terms(f, b, w, (FALLING,), duty).parameters()[FALLING.name]
    k_f = nothing["k_f_J_per_m3_at_100kHz_0.1T"]
    assert k_f[0] < 1e-8 and math.isnan(k_f[1])
    assert _param_json(nothing)["k_f_J_per_m3_at_100kHz_0.1T"]["std"] is None
    assert "not determined by the rows" in form(FALLING, nothing) and "e-21" not in form(FALLING, nothing)
    json.dumps(_param_json(nothing), allow_nan=False)

    f, b, w, duty = table(1, series=SERIES_TRUTH)
    found = _param_json(fit_terms(f, b, w, (SERIES,), duty).parameters()[SERIES.name])
    for key, truth in zip(("k_1_J_per_m3_at_100kHz_0.1T", "delta_1", "k_2_J_per_m3_at_100kHz_0.1T", "delta_2"),
                          SERIES_TRUTH):
        assert found[key]["std"] is not None and _within(found[key], truth), key
