"""``calibrate``'s picture of one recording: the data before and after, and the directions
covered.

Kept apart from the sweep figures (and their pandas) because ``calibrate`` draws it in a
second process (:mod:`magbench.cli.picture`) whose start-up is on the command's critical path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from magbench.figures.style import new_figure

__all__ = ["PictureLayout", "calibration_picture", "picture_layout"]


def _lon_lat(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    return (np.degrees(np.arctan2(u[..., 1], u[..., 0])),
            np.degrees(np.arcsin(np.clip(u[..., 2], -1.0, 1.0))))


def _gap_outline(centre: np.ndarray, radius_deg: float, n: int = 181) -> np.ndarray:
    """Points on the circle of angular radius ``radius_deg`` about ``centre`` (unit rows)."""
    c = centre / np.linalg.norm(centre)
    a = np.cross(c, np.eye(3)[int(np.argmin(np.abs(c)))])
    a /= np.linalg.norm(a)
    b = np.cross(c, a)
    t = np.linspace(0, 2 * np.pi, n)[:, None]
    r = np.radians(radius_deg)
    return np.cos(r) * c + np.sin(r) * (np.cos(t) * a + np.sin(t) * b)


#: The projections of rows 1-2: (horizontal axis, vertical axis, their names).
_PAIRS = [(0, 1, "x", "y"), (0, 2, "x", "z"), (1, 2, "y", "z")]
_ROW_TITLES = ["before (scaled to unit mean norm)", "after: m = A (y - b)"]


@dataclass
class PictureLayout:
    """The figure and axes of :func:`calibration_picture` with everything that does not depend
    on the data: ``axes`` holds the projections row by row, then the directions (third row)."""

    fig: Figure
    axes: list[Axes]

    @property
    def rows(self) -> int:
        return 3 if len(self.axes) == 7 else 2


def picture_layout(rows: int = 3) -> PictureLayout:
    """The data-free part of :func:`calibration_picture` (``rows`` 3 with the directions, 2
    without): figure, axes, ticks, labels and titles.

    Building the axes is about a quarter of the picture's time; the picture process builds
    them while it waits for the data (:mod:`magbench.cli.picture`). The picture drawn on it
    is the same, pixel for pixel, as on a layout built afterwards.
    """
    # A fixed layout: the constrained one measures every tick label and took half the time
    # of drawing this figure (calibrate's speed target includes the picture).
    fig = new_figure(11, 3.6 * rows, layout=None)
    grid = fig.add_gridspec(rows, 3, left=0.07, right=0.97, bottom=0.06, top=0.93,
                            hspace=0.35, wspace=0.3)
    axes = []
    for row, what in enumerate(_ROW_TITLES):
        for col, (_, _, a, b) in enumerate(_PAIRS):
            ax = fig.add_subplot(grid[row, col])
            ax.set_xticks([-1, 0, 1])        # few tick labels: text is most of the drawing time
            ax.set_yticks([-1, 0, 1])
            ax.set_aspect("equal")
            ax.set_xlabel(a)
            ax.set_ylabel(b)
            if col == 1:    # one title per row: text is most of the drawing time
                ax.set_title(what, fontsize=9)
            axes.append(ax)
    if rows == 3:
        ax = fig.add_subplot(grid[2, :])
        ax.set_xlim(-180, 180)
        ax.set_ylim(-90, 90)
        ax.set_xticks(range(-180, 181, 90))
        ax.set_yticks(range(-90, 91, 45))
        ax.grid(alpha=0.3)
        ax.set_xlabel("longitude in the sensor's axes (deg, from +X toward +Y)")
        ax.set_ylabel("latitude (deg, toward +Z)")
        ax.set_title("field directions covered (after calibration)", fontsize=9)
        axes.append(ax)
    return PictureLayout(fig, axes)


def calibration_picture(before: np.ndarray, after: np.ndarray, title: str = "", *,
                        inliers: np.ndarray | None = None,
                        thinned: np.ndarray | None = None,
                        before_title: str | None = None,
                        directions: np.ndarray | None = None,
                        gap_centre: np.ndarray | None = None,
                        gap_deg: float | None = None,
                        layout: PictureLayout | None = None) -> Figure:
    """The data before and after calibration, with unit circles, and the directions covered.

    Rows 1-2: the three 2-D projections before (scaled to unit mean norm, so both rows share
    the unit circle as reference) and after; a good calibration puts the points of every
    projection inside the circle and the outermost ones on it (a sphere's projection is a
    filled disc). Samples set aside as outliers (``inliers`` False) are drawn as red crosses,
    samples dropped by thinning (``thinned`` True: their direction was sampled enough) as grey
    dots under the kept ones. ``before_title`` replaces the first row's title.
    Row 3 (with ``directions``): the corrected field directions as longitude and latitude in
    the sensor's axes (longitude from +X toward +Y, latitude toward +Z), and the largest
    uncovered cap (centre ``gap_centre``, radius ``gap_deg``) outlined.

    ``layout``: an unused :func:`picture_layout` to draw on (ignored if its number of rows
    does not match); by default one is built here.
    """
    rows = 3 if directions is not None else 2
    if layout is None or layout.rows != rows:
        layout = picture_layout(rows)
    fig, axes = layout.fig, layout.axes
    circle = np.linspace(0, 2 * np.pi, 361)
    good = np.ones(len(before), bool) if inliers is None else np.asarray(inliers, bool)
    thin = np.zeros(len(before), bool) if thinned is None else np.asarray(thinned, bool) & good
    kept = good & ~thin
    if before_title:
        axes[1].set_title(before_title, fontsize=9)
    for row, data in enumerate([before, after]):
        lim = max(1.2, 1.05 * float(np.abs(data[good]).max()))
        for col, (i, j, _, _) in enumerate(_PAIRS):
            ax = axes[3 * row + col]
            ax.plot(np.cos(circle), np.sin(circle), color="crimson", lw=1.0, label="unit circle")
            if thin.any():
                ax.plot(data[thin, i], data[thin, j], ".", ms=1.5, alpha=0.4, color="0.6",
                        label="thinned (direction already sampled)")
            # plot() with small markers draws far faster than scatter() for thousands of points
            ax.plot(data[kept, i], data[kept, j], ".", ms=1.5, alpha=0.5, color="#4c72b0",
                    label="kept")
            if not good.all():
                ax.plot(np.clip(data[~good, i], -lim, lim), np.clip(data[~good, j], -lim, lim),
                        "x", ms=4, color="crimson", label="set aside (outlier)")
            ax.plot([0], [0], "+", color="black")
            ax.set_xlim(-lim, lim)
            ax.set_ylim(-lim, lim)
            if row == 0 and col == 0:
                ax.legend(fontsize=8, loc="upper right")
    if directions is not None:
        ax = axes[6]
        lon, lat = _lon_lat(np.asarray(directions, float))
        ax.plot(lon, lat, ".", ms=2, alpha=0.4, color="#4c72b0", label="field directions")
        if gap_centre is not None and gap_deg is not None:
            glon, glat = _lon_lat(_gap_outline(np.asarray(gap_centre, float), gap_deg))
            # break the outline where it wraps around at +-180 deg of longitude
            jumps = np.flatnonzero(np.abs(np.diff(glon)) > 180) + 1
            for k, (x, y) in enumerate(zip(np.split(glon, jumps), np.split(glat, jumps),
                                           strict=True)):
                ax.plot(x, y, "--", color="crimson", lw=1.2,
                        label=f"largest uncovered cap ({gap_deg:.0f} deg)" if k == 0 else None)
            clon, clat = _lon_lat(np.asarray(gap_centre, float))
            ax.plot([clon], [clat], "*", ms=10, color="crimson")
        ax.legend(fontsize=8, loc="lower right")
    if title:
        fig.suptitle(title)
    return fig
