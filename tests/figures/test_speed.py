"""The scale figure from a hand-made scale.csv."""

import pandas as pd
from PIL import Image

from magbench.figures.speed import plot_scale
from magbench.figures.style import DPI


def test_scale_figure_is_one_png_of_two_panels(tmp_path):
    scale = pd.DataFrame({"trials": [1000, 10000], "methods": 2, "run_s": [9.0, 90.0],
                          "summarize_s": [0.05, 0.1], "intervals_s": [0.1, 1.0],
                          "peak_rss_mb": [110.0, 130.0], "worker_peak_rss_mb": [80.0, 82.0]})
    path = plot_scale(scale, tmp_path / "scale.png")
    with Image.open(path) as image:
        assert image.format == "PNG" and image.size == (10 * DPI, round(4.2 * DPI))
