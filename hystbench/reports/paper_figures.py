"""The figures of ``hystbench paper``, drawn as the paper draws them (numbers in the names are the
paper's figure numbers).  matplotlib, Agg backend, PNG."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..config import load_rig
from ..analysis.force_error import ForceError, analytical_model
from .paper import EcoreRun, PaperResult
from .figures import draw_nested_loops, plt, save_figure as _save, zoom_on_the_middle

__all__ = ["paper_figures"]

_DF = "$\\Delta F$ (N)"
_FZ = "$F_z$ (N)"
_I = "Current (A)"
_B2 = "$B^2$ (T$^2$)"



def _style(ax, xlabel, ylabel, *, legend=True, title=None):
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    if title:
        ax.set_title(title, fontsize=10)
    if legend:
        ax.legend(fontsize=7.5)


def _closed(x):
    return np.append(x, x[0])


def _sym(ax, curves):
    m = max(float(np.max(np.abs(c))) for c in curves)
    ax.set_ylim(-1.15 * m, 1.15 * m)


# --- Sec. IV: the instrument --------------------------------------------------------------------
def _bode(res: PaperResult, out: Path) -> Path:
    fit = res.instrument
    k = fit.params["force_constant_N_per_A"]
    f_mod = np.geomspace(10, 45000, 2000)
    h_mod = k * fit.model.frequency_response(f_mod)
    ph_mod = np.degrees(np.unwrap(np.angle(h_mod)))
    fig = plt.figure(figsize=(10, 7.2))
    ax_a, ax_b = fig.add_subplot(2, 2, 1), fig.add_subplot(2, 2, 3)
    ax_c = fig.add_subplot(1, 2, 2)
    names = {"voicecoil_ferrite": "Ferrite magnet", "voicecoil_ndfeb": "NdFeB magnet", "voicecoil_smco": "SmCo magnet"}
    marks = {"voicecoil_ferrite": "o-", "voicecoil_ndfeb": "s-", "voicecoil_smco": "^:"}
    seen: dict[str, np.ndarray] = {}
    for rig, rf in res.fits.items():
        r = rf.response
        ph_ref = np.interp(np.log(r.frequency_hz), np.log(f_mod), ph_mod)
        ph = ph_ref + np.degrees(np.angle(np.exp(1j * (np.angle(r.h) - np.radians(ph_ref)))))
        lab = names.get(rig, rig)
        twin = next((n for n, p in seen.items() if p.shape == ph.shape and np.median(np.abs(p - ph)) < 0.5), None)
        if twin is not None:  # e.g. NdFeB and SmCo presets lag alike: say so, or one curve seems lost
            lab += f" (on the {twin} curve)"
        seen[names.get(rig, rig).split()[0]] = ph
        mk = marks.get(rig, "o-")
        ax_a.semilogx(r.frequency_hz, 20 * np.log10(np.abs(r.h)), mk, ms=3.5, lw=0.9, label=lab)
        ax_b.semilogx(r.frequency_hz, ph, mk, ms=3.5, lw=0.9, label=lab)
        z = (r.frequency_hz >= 100) & (r.frequency_hz <= 4500)
        ax_c.plot(r.frequency_hz[z], ph[z], mk, ms=4, lw=0.9, label=lab)
    lab = f"Modeled instr. resp. (fit to {names.get(res.benchmark, res.benchmark).lower()})"
    ax_a.semilogx(f_mod, 20 * np.log10(np.abs(h_mod)), "k--", lw=1, label=lab)
    ax_b.semilogx(f_mod, ph_mod, "k--", lw=1, label=lab)
    z = (f_mod >= 100) & (f_mod <= 4500)
    ax_c.plot(f_mod[z], ph_mod[z], "k--", lw=1, label=lab)
    _style(ax_a, "Frequency (Hz)", "Amplitude (dB re 1 N/A)", title="(a) amplitude, force per current")
    _style(ax_b, "Frequency (Hz)", "Phase (°)", legend=False, title="(b) phase")
    ax_b.set_yticks([-360, -270, -180, -90, 0, 90])
    _style(ax_c, "Frequency (Hz)", "Phase (°)", title="(c) phase, 100-4500 Hz (magnified)")
    ax_c.set_ylim(-50, 10)
    fig.suptitle("Fig. 7: voice coil on the load cell, three magnets, and the two-filter model", fontsize=11)
    return _save(fig, out)


def _instrument_model(res: PaperResult, out: Path) -> Path:
    m = res.instrument.model
    f = np.linspace(100, 4500, 800)

    def lpf(fc, z):
        x = f / fc
        return -np.degrees(np.arctan2(2 * z * x, 1 - x * x))

    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    ax.plot(f, lpf(m.fn_hz, m.zeta_n), label=f"Mechanical resp. $H_{{mech}}$ ({m.fn_hz:.0f} Hz, ζ={m.zeta_n:.4f})")
    ax.plot(f, lpf(m.f0_hz, m.zeta_0), label=f"Low-pass filter $H_{{LPF}}$ ({m.f0_hz:.0f} Hz, ζ={m.zeta_0:.3f})")
    ax.plot(f, m.phase_deg(f), "k", lw=1.6, label="Modeled instrument resp.")
    ax.set_ylim(-50, 2)
    _style(ax, "Frequency (Hz)", "Phase (°)", title="Fig. 9: phase of the fitted instrument model, θ$_{instr}$")
    return _save(fig, out)


# --- Secs. V-VII: the E-core ---------------------------------------------------------------------
def _analytic(ax, run: EcoreRun, fe: ForceError):
    i = np.linspace(fe.current_a.min(), fe.current_a.max(), 200)
    ax.plot(i, analytical_model(run.rig).static_force(i), "k--", lw=1.3, label="Analyt. model", zorder=20)


def _loops(run: EcoreRun, out: Path, fig_no: str, title: str) -> Path:
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.4))
    series = run.series()
    labels = [f"{fe.nominal_frequency_hz:g} Hz, meas." for fe in series]
    # nested: the loops lie almost on one another, and drawn alike the last hid the first (40 Hz)
    forces = [(lab, _closed(fe.current_a), _closed(fe.force_n)) for lab, fe in zip(labels, series)]
    draw_nested_loops(a, forces)
    draw_nested_loops(b, [(lab, _closed(fe.current_a), _closed(fe.errors_n["before"]))
                          for lab, fe in zip(labels, series)])
    _analytic(a, run, series[0])
    _sym(b, [fe.errors_n["before"] for fe in series])
    _style(a, _I, _FZ, title="(a) current vs force")
    zoom_on_the_middle(a, forces)
    _style(b, _I, _DF, title="(b) force error, Eq. 5 (measured - Eq. 1)")
    fig.suptitle(f"Fig. {fig_no}: {title}", fontsize=11)
    return _save(fig, out)


def _b2(fe: ForceError, run: EcoreRun):
    g = load_rig(run.rig)["geometry"]
    area = float(g["outer_tooth_width_m"]) * float(g["depth_m"])
    return (fe.average.channels["flux_Wb"] / area) ** 2


def _linear_fit(x, y):
    a = np.vstack([np.ones_like(x), x]).T
    coef = np.linalg.lstsq(a, y, rcond=None)[0]
    return a @ coef


def _flux_squared(run: EcoreRun, out: Path) -> Path:
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.4))
    series = run.series()
    for fe in series:
        b2 = _b2(fe, run)
        lab = f"{fe.nominal_frequency_hz:g} Hz, meas."
        a.plot(_closed(b2), _closed(fe.force_n), lw=1, label=lab)
        b.plot(_closed(b2), _closed(fe.force_n - _linear_fit(b2, fe.force_n)), lw=1, label=lab)
    _style(a, _B2, _FZ, title="(a) squared flux density in the sensed tooth vs force")
    _style(b, _B2, _DF, title="(b) force minus its linear fit in $B^2$")
    fig.suptitle("Fig. 11: E-core without magnet, force against $B^2$: only the instrument's delay "
                 "opens these loops", fontsize=11)
    return _save(fig, out)


def _at_320(run: EcoreRun, out: Path, fig_no: str, title: str, with_b2: bool) -> Path:
    fe = run.error(320.0)
    rows = 2 if with_b2 else 1
    fig, axes = plt.subplots(rows, 2, figsize=(11, 4.2 * rows), squeeze=False)
    lab_m, lab_c = "320 Hz, meas.", f"320 Hz, sens. comp. ({360 * fe.frequency_hz * fe.instrument_delay_s:.2f}°)"
    i = _closed(fe.current_a)
    if with_b2:
        b2 = _closed(_b2(fe, run))
        line = _linear_fit(b2, _closed(fe.force_corrected_n))
        axes[0, 0].plot(b2, _closed(fe.force_n), lw=1, label=lab_m)
        axes[0, 0].plot(b2, _closed(fe.force_corrected_n), lw=1, label=lab_c)
        axes[0, 1].plot(b2, _closed(fe.force_n) - line, lw=1, label=lab_m)
        axes[0, 1].plot(b2, _closed(fe.force_corrected_n) - line, lw=1, label=lab_c)
        _style(axes[0, 0], _B2, _FZ, title="Fig. 12(a): $B^2$ vs force")
        _style(axes[0, 1], _B2, _DF, title="Fig. 12(b): force minus its linear fit in $B^2$")
    a, b = axes[-1]
    a.plot(i, _closed(fe.force_n), lw=1, label=lab_m)
    a.plot(i, _closed(fe.force_corrected_n), lw=1, label=lab_c)
    _analytic(a, run, fe)
    b.plot(i, _closed(fe.errors_n["before"]), lw=1, label=lab_m)
    b.plot(i, _closed(fe.errors_n["instrument"]), lw=1, label=lab_c)
    _sym(b, [fe.errors_n["before"]])
    n = "13" if with_b2 else fig_no
    _style(a, _I, _FZ, title=f"Fig. {n}(a): current vs force")
    _style(b, _I, _DF, title=f"Fig. {n}(b): force error, Eq. 5")
    fig.suptitle(f"Fig. {fig_no}: {title}", fontsize=11)
    return _save(fig, out)


def _errors(ax, run: EcoreRun, kind: str, suffix: str, ylim=None):
    series = run.series()
    for fe in series:
        ax.plot(_closed(fe.current_a), _closed(fe.errors_n[kind]), lw=1,
                label=f"{fe.nominal_frequency_hz:g} Hz, {suffix}")
    if ylim is None:
        _sym(ax, [fe.errors_n[kind] for fe in series])
    else:
        ax.set_ylim(*ylim)


def _sens_comp(run: EcoreRun, out: Path) -> Path:
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    _errors(ax, run, "instrument", "sens. comp.")
    _style(ax, _I, _DF, title="Fig. 16: E-core with magnet, force error after the instrument correction")
    return _save(fig, out)


def _fig17(run: EcoreRun, out: Path) -> Path:
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    for ipp in sorted({k[1] for k in run.errors}):
        fes = run.series(ipp)
        ax.plot([fe.nominal_frequency_hz for fe in fes],
                [100 * fe.eye_n("instrument") / fe.force_range_n for fe in fes],
                "o-", label=f"{ipp:g} A-pp, sens. comp.")
    ax.set_xlim(0, 500)
    ax.set_ylim(bottom=0)
    _style(ax, "Frequency (Hz)", "$\\Delta F_{max}/F_{range}$ (%)",
           title="Fig. 17: loop-eye height at i = 0 over the force range (magnet)")
    return _save(fig, out)


def _fig18(res: PaperResult, out: Path) -> Path:
    fit = res.instrument
    r = fit.response
    f_mod = np.geomspace(10, 45000, 2000)
    ph_mod = fit.model.phase_deg(f_mod)
    ph_ref = np.interp(np.log(r.frequency_hz), np.log(f_mod), ph_mod)
    ph = ph_ref + np.degrees(np.angle(np.exp(1j * (np.angle(r.h) - np.radians(ph_ref)))))
    pts = []
    for run in res.ecore.values():
        for d in run.delays:
            ff = d.harmonic * d.frequency_hz
            pts.append((ff, -360.0 * ff * d.delays_s["instrument"], "ecore_pm" in run.rig))
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.4))
    for ax, zoom in ((a, False), (b, True)):
        sel = (r.frequency_hz >= 100) & (r.frequency_hz <= 2000) if zoom else np.ones(r.frequency_hz.size, bool)
        fm = (f_mod >= 100) & (f_mod <= 2000) if zoom else np.ones(f_mod.size, bool)
        ax.plot(r.frequency_hz[sel], ph[sel], "o-", ms=3.5, lw=0.8, label="Ferrite magnet (voice coil)")
        ax.plot(f_mod[fm], ph_mod[fm], "k--", lw=1, label="Modeled instrument resp.")
        for magnet, mk, lab in ((False, "x", "Phase angle $F_z$-$\\Phi^2$ (E-core, no magnet)"),
                                (True, "+", "Phase angle $F_z$-$\\Phi$ (E-core, magnet)")):
            q = [(f, p) for f, p, m in pts if m is magnet and (not zoom or 100 <= f <= 2000)]
            if q:
                ax.plot(*zip(*q), mk, ms=8, mew=1.5, ls="none", label=lab)
        ax.set_xscale("log")
    a.set_yticks([-270, -180, -90, 0, 90, 180])
    b.set_ylim(-10, 5)
    b.set_xlim(100, 2000)
    _style(a, "Frequency (Hz)", "Phase (°)", title="(a) instrument phase, voice coil and E-core")
    _style(b, "Frequency (Hz)", "Phase (°)", title="(b) magnified, 100-2000 Hz")
    fig.suptitle("Fig. 18: the instrument's phase measured from force and flux of the E-core (at the force's "
                 "frequency) against the voice-coil identification", fontsize=10)
    return _save(fig, out)


def _fig19(res: PaperResult, out: Path) -> Path:
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.4))
    for ax, rig, lab in ((a, "ecore", "(a) E-core without magnet"), (b, "ecore_pm", "(b) E-core with magnet")):
        run = res.ecore[rig]
        # the same scale as the force error before compensation (paper: +-0.2 N and +-5 N)
        m = max(float(np.max(np.abs(fe.errors_n["before"]))) for fe in run.series())
        _errors(ax, run, "hysteresis", "hyst. comp.", ylim=(-1.15 * m, 1.15 * m))
        _style(ax, _I, _DF, title=lab + ", after Eq. 6")
    fig.suptitle("Fig. 19: force error after hysteresis compensation (phase-delay model, Eq. 6); "
                 "axes as in Figs. 10 and 14", fontsize=10)
    return _save(fig, out)


def paper_figures(res: PaperResult, out: Path) -> list[Path]:
    """Every figure; returns their paths."""
    out = Path(out)
    ecore, pm = res.ecore["ecore"], res.ecore["ecore_pm"]
    paths = [_bode(res, out / "fig07_bode.png"), _instrument_model(res, out / "fig09_instrument_model.png"),
             _loops(ecore, out / "fig10_ecore_loops.png", "10", "E-core without magnet, "
                    f"{ecore.main_ipp_a:g} A-pp (period-averaged)"),
             _flux_squared(ecore, out / "fig11_ecore_flux_squared.png")]
    if (320.0, ecore.main_ipp_a) in ecore.errors:
        paths.append(_at_320(ecore, out / "fig12_13_ecore_320hz.png", "12-13",
                             "E-core without magnet at 320 Hz, with and without the instrument's phase "
                             "correction", True))
    paths.append(_loops(pm, out / "fig14_ecore_pm_loops.png", "14",
                        f"E-core with magnet, {pm.main_ipp_a:g} A-pp (period-averaged)"))
    if (320.0, pm.main_ipp_a) in pm.errors:
        paths.append(_at_320(pm, out / "fig15_ecore_pm_320hz.png", "15",
                             "E-core with magnet at 320 Hz, with and without the instrument's phase correction",
                             False))
    paths += [_sens_comp(pm, out / "fig16_ecore_pm_sens_comp.png"), _fig17(pm, out / "fig17_force_error_vs_f.png"),
              _fig18(res, out / "fig18_instrument_phase.png"), _fig19(res, out / "fig19_hyst_comp.png")]
    return paths
