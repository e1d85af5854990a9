"""calibrate's picture: drawn on a layout built in advance, it is the same file."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.core.geometry import fibonacci_sphere
from magbench.figures.calibration import calibration_picture, picture_layout
from magbench.figures.style import save_figure


def arrays(directions: bool, outliers: bool) -> dict:
    m = fibonacci_sphere(400)
    inliers = np.ones(400, bool)
    if outliers:
        inliers[::37] = False
    out = {"before": np.array([1.3, 0.8, 1.1]) * m + 0.2, "after": m, "title": "rec.csv: fang",
           "inliers": inliers}
    if directions:
        out |= {"directions": m[m[:, 2] < 0.7], "gap_centre": np.array([0.0, 0.3, 1.0]),
                "gap_deg": 35.0}
    return out


@pytest.mark.parametrize("directions", [True, False])
@pytest.mark.parametrize("outliers", [True, False])
def test_a_picture_on_a_layout_built_in_advance_is_the_same_file(tmp_path, directions,
                                                                 outliers):
    kwargs = arrays(directions, outliers)
    fresh = save_figure(calibration_picture(**kwargs), tmp_path / "fresh.png", dpi=40)
    layout = picture_layout(3)           # what the picture process builds while it waits
    fig = calibration_picture(**kwargs, layout=layout)
    # a three-row layout serves a picture with directions; without, a two-row one is built
    assert (fig is layout.fig) == directions
    assert save_figure(fig, tmp_path / "ahead.png", dpi=40).read_bytes() == fresh.read_bytes()


def test_the_layout_has_the_rows_asked_for():
    assert picture_layout(3).rows == 3 and len(picture_layout(3).axes) == 7
    assert picture_layout(2).rows == 2 and len(picture_layout(2).axes) == 6
