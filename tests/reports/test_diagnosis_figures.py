"""The locate heat map is written as a readable PNG."""

from __future__ import annotations

import matplotlib.image as mpimg

from hystbench.analysis.diagnosis.locate import ResidualEntry, locate
from hystbench.reports.diagnosis_figures import heat_map


def test_heat_map_is_a_png_with_the_hot_cell(tmp_path):
    entries = [ResidualEntry(r, rig, f, a, 10.0 * r, "force_N", "force vs flux", str(k), 800.0 if (r, k) == (3, 0) else 2.0, 2)
               for r, (rig, f, a) in enumerate([("ecore", 40.0, 1.27), ("ecore", 120.0, 1.27),
                                                ("ecore_pm", 40.0, 0.7), ("ecore_pm", 120.0, 0.7)])
               for k in range(3)]
    path = heat_map(locate(entries, floor_note="model-error floor: 1 % of each harmonic"), tmp_path / "map.png")
    image = mpimg.imread(path)
    assert image.shape[0] > 100 and image.shape[1] > 100
    red = (image[..., 0] > 0.5) & (image[..., 1] < 0.2) & (image[..., 2] < 0.2)
    assert red.any()  # the hot cell is drawn at the red end


def test_heat_map_of_nothing_says_so(tmp_path):
    path = heat_map(locate([]), tmp_path / "empty.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
