"""The loss-table figure is written as a PNG of the size asked for, for a core-loss and a
complex-permeability table."""

from __future__ import annotations

from pathlib import Path

import matplotlib.image as mpimg
import pytest

from hystbench.reports.loss_figures import loss_separation_figure

REAL = Path(__file__).resolve().parents[1] / "data" / "real"


@pytest.mark.parametrize("name", ["magnet_N87_sine", "N87_mu_large"])
def test_figure_written(tmp_path: Path, name: str):
    out = loss_separation_figure(REAL / f"{name}.csv", tmp_path / "sub" / f"{name}.png")
    img = mpimg.imread(out)
    assert out.suffix == ".png" and img.shape[0] == round(4.8 * 110) and img.shape[1] == 12 * 110
    assert img[..., :3].std() > 0.05  # something was drawn, not a blank page
