"""Issue 30, item 10: figures a new user could not read.  (a) loops that lie almost on one another
are all visible; (b) the diagnosis's "after" residual has its own scale, and says so; (c) the heat
map explains k and its grey cells; (d) the force map has a colour bar."""

from __future__ import annotations

from pathlib import Path

import matplotlib.colors as mcolors
import matplotlib.image as mpimg
import numpy as np

from hystbench.analysis.diagnosis.locate import ResidualEntry, locate
from hystbench.analysis.diagnosis.result import Loops
from hystbench.reports import diagnosis, diagnosis_figures, figures


def spy_on(monkeypatch, module) -> list:
    """The figures ``module`` saves, kept open for inspection (and still written)."""
    seen, save = [], module.save_figure

    def keep(fig, path, *args, **kw):
        seen.append(fig)
        texts = [t.get_text() for t in fig.findobj(lambda a: hasattr(a, "get_text"))]
        fig._texts_seen = " ".join(" ".join(texts).split())  # wrapped lines joined
        colours = [[mcolors.to_rgb(line.get_color()) for line in ax.lines] for ax in fig.axes]
        fig._colours_seen, fig._ylims_seen = colours, [ax.get_ylim() for ax in fig.axes]
        fig._ylabels_seen = [ax.get_ylabel() for ax in fig.axes]
        return save(fig, path, *args, **kw)

    monkeypatch.setattr(module, "save_figure", keep)
    return seen


def test_five_nearly_coincident_loops_are_each_visible(tmp_path: Path, monkeypatch):
    seen = spy_on(monkeypatch, figures)
    t = np.linspace(0.0, 2 * np.pi, 400)
    x = 0.7 * np.cos(t)  # as ecore_pm's current-force loops at 40..480 Hz: openings of 1-3.4 N on 95 N
    curves = [(f"{f:g} Hz", x, 177.0 + 68.0 * x + w * np.sin(t))
              for f, w in zip((40, 80, 160, 320, 480), (1.0, 1.3, 1.8, 2.6, 3.4))]
    image = mpimg.imread(figures.loops_figure(curves, "current (A)", "force (N)", "loops", tmp_path / "l.png"))[..., :3]
    pixels = [int((np.abs(image - np.array(c)).max(axis=-1) < 0.08).sum()) for c in seen[0]._colours_seen[0]]
    assert len(pixels) == 5
    assert min(pixels) >= 0.15 * max(pixels), pixels  # none hidden under the others (40 Hz was: 9 %)


def test_the_after_residual_has_its_own_scale_and_says_so(tmp_path: Path, monkeypatch):
    seen = spy_on(monkeypatch, diagnosis)
    ph = np.arange(200) / 200
    w = 2 * np.pi * ph
    measured = {"current_A": np.cos(w), "flux_Wb": 1e-4 * np.cos(w - 0.05), "force_N": 170 + 40 * np.cos(w - 0.08)}
    before = {"flux_Wb": 1e-4 * np.cos(w), "force_N": 170 + 40 * np.cos(w - 0.02)}  # residuals of 2.4 N ...
    after = {"flux_Wb": measured["flux_Wb"] + 2e-7 * np.sin(3 * w), "force_N": measured["force_N"] + 0.05 * np.sin(2 * w)}
    loops = Loops("run", "ecore_pm", 320.0, 1.4, ph, measured, before, after)  # ... and 0.05 N after
    diagnosis.loops_figure(loops, tmp_path / "loops.png", {"flux_Wb": 2e-8, "force_N": 0.01})
    fig = seen[0]
    before_lim, after_lim = fig._ylims_seen[2][1], fig._ylims_seen[5][1]  # the residual column, rows 1 and 2
    assert 10.0 <= after_lim <= 12.0  # its own: the largest after residual is 10 noise floors (flux)
    assert before_lim > 20 * after_lim
    assert "own scale" in fig._ylabels_seen[5]


def test_the_heat_map_explains_k_and_its_grey_cells(tmp_path: Path, monkeypatch):
    seen = spy_on(monkeypatch, diagnosis_figures)
    entries = [ResidualEntry(r, "ecore", f, 1.27, 10.0 * r, "force_N", "force vs flux", str(k), 5.0, 2)
               for r, f in enumerate((40.0, 120.0)) for k in range(3) if (r, k) != (1, 2)]  # one cell missing
    diagnosis_figures.heat_map(locate(entries), tmp_path / "map.png")
    text = seen[0]._texts_seen
    assert "k=0" in text  # the rows as before
    assert "the harmonic" in text and "k = 0 the mean" in text
    assert "Grey: no such cell" in text


def test_the_force_map_has_a_colour_bar(tmp_path: Path, monkeypatch):
    seen = spy_on(monkeypatch, figures)
    figures.force_map_figure("ecore_pm", tmp_path / "map.png")
    fig = seen[0]
    assert len(fig.axes) == 2  # the surface's axes and its colour bar
    assert "F_z" in fig._ylabels_seen[1] and "(N)" in fig._ylabels_seen[1]
