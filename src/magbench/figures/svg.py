"""Interactive line charts as inline SVG, for the HTML report: no library, no network.

A point's ``<title>`` is what a browser shows on hover: the method, the x value, the value
drawn and the n behind it. Colours and markers' colours are the figures' own
(:func:`magbench.figures.style.method_style`), so a method looks the same in the PNG and here.
"""

from __future__ import annotations

from html import escape

import numpy as np
import pandas as pd

from magbench.figures.style import method_style

__all__ = ["line_chart_svg"]

_W, _H = 640, 300
_LEFT, _RIGHT, _TOP, _BOTTOM = 60, 170, 28, 44


def _ticks(lo: float, hi: float, log: bool) -> list[float]:
    if log:
        return [10.0 ** e for e in range(int(np.floor(lo)), int(np.ceil(hi)) + 1)]
    return list(np.linspace(lo, hi, 5))


def _fmt(v: float) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v:.3g}"


def line_chart_svg(data: pd.DataFrame, y: str, title: str, *, x: str = "x",
                   logx: bool = False, logy: bool = False, categorical: bool = False,
                   n: str = "n", n_used: str | None = "n_meaningful") -> str:
    """One panel: ``y`` against ``x``, a line per ``series`` (labels from ``label``).

    Parameters
    ----------
    data : DataFrame
        Columns ``series``, ``label``, ``x``, ``y``, ``n`` and, when given, ``n_used`` (the
        runs the value averages over), one row per (series, x).
    y, title : str
        The column drawn and the panel's title.
    logx, logy : bool
        Logarithmic axes (non-positive values are left out).
    categorical : bool
        ``x`` holds labels, drawn evenly in their first-seen order.

    Returns
    -------
    str
        An ``<svg>`` element; every point has a ``<title>`` (hover) with its value and n.
    """
    d = data[data[y].notna()].copy()
    if logy:
        d = d[d[y] > 0]
    if d.empty:
        return ""
    cats = list(dict.fromkeys(d[x])) if categorical else []
    xs = (np.array([cats.index(v) for v in d[x]], float) if categorical
          else np.asarray(d[x], float))
    if logx and not categorical:
        keep = xs > 0
        d, xs = d[keep], np.log10(xs[keep])
    ys = np.asarray(d[y], float)
    ys = np.log10(ys) if logy else ys
    x0, x1 = (xs.min(), xs.max()) if xs.max() > xs.min() else (xs.min() - 1, xs.max() + 1)
    y0, y1 = (ys.min(), ys.max()) if ys.max() > ys.min() else (ys.min() - 1, ys.max() + 1)
    if logy:
        y0, y1 = np.floor(y0), np.ceil(y1)
    # tall enough for the legend: one line per series
    H = max(_H, _TOP + 16 + 13 * d["series"].nunique())
    pw, ph = _W - _LEFT - _RIGHT, H - _TOP - _BOTTOM

    def px(v: float) -> float:
        return _LEFT + (v - x0) / (x1 - x0) * pw

    def py(v: float) -> float:
        return _TOP + ph - (v - y0) / (y1 - y0) * ph

    out = [f'<svg class="chart" viewBox="0 0 {_W} {H}" width="{_W}" height="{H}" '
           f'role="img" xmlns="http://www.w3.org/2000/svg"><title>{escape(title)}</title>',
           f'<text x="{_LEFT}" y="16" class="ct">{escape(title)}</text>',
           f'<rect x="{_LEFT}" y="{_TOP}" width="{pw}" height="{ph}" fill="none" '
           'stroke="#999"/>']
    for t in _ticks(y0, y1, logy):
        v = np.log10(t) if logy else t
        if y0 - 1e-9 <= v <= y1 + 1e-9:
            out.append(f'<text x="{_LEFT - 4}" y="{py(v) + 4:.1f}" class="tk" '
                       f'text-anchor="end">{_fmt(t)}</text>')
    xt = (list(enumerate(cats)) if categorical else
          [(np.log10(t) if logx else t, t) for t in sorted(set(np.asarray(d[x], float)))])
    for v, lab in xt:
        out.append(f'<text x="{px(v):.1f}" y="{_TOP + ph + 14}" class="tk" '
                   f'text-anchor="middle">{escape(str(lab) if categorical else _fmt(lab))}'
                   '</text>')
    d = d.assign(_px=[px(v) for v in xs], _py=[py(v) for v in ys])
    for i, (name, part) in enumerate(d.groupby("series", sort=False)):
        colour = method_style(str(name))["color"] if name != "efficient_selection" else "#555"
        label = str(part["label"].iloc[0]).replace("\n", " ")
        pts = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(part["_px"], part["_py"],
                                                           strict=True))
        out.append(f'<g class="series"><title>{escape(label)}</title>'
                   f'<polyline points="{pts}" fill="none" stroke="{colour}" '
                   'stroke-width="1.5"/>')
        for rec in part.to_dict("records"):
            used = rec.get(n_used) if n_used else None
            tip = (f"{label}, {x} = {rec[x]}: {y} = {_fmt(rec[y])} (n = {_fmt(rec.get(n))}"
                   + (f", meaningful {_fmt(used)}" if used is not None else "") + ")")
            out.append(f'<circle cx="{rec["_px"]:.1f}" cy="{rec["_py"]:.1f}" r="3.5" '
                       f'fill="{colour}"><title>{escape(tip)}</title></circle>')
        ly = _TOP + 10 + 13 * i
        out.append(f'<line x1="{_W - _RIGHT + 8}" y1="{ly - 4}" x2="{_W - _RIGHT + 22}" '
                   f'y2="{ly - 4}" stroke="{colour}" stroke-width="2"/>'
                   f'<text x="{_W - _RIGHT + 26}" y="{ly}" class="lg">{escape(label)}</text>'
                   '</g>')
    out.append("</svg>")
    return "".join(out)
