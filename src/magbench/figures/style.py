"""The one figure style: a fixed colour, marker and line per method, and one atomic save.

A method keeps its colour and marker in every figure. The palette is built from colour-blind
safe sets (Okabe and Ito's eight, then Paul Tol's "muted" and "light" schemes), the review's
seven methods first in the strongest colours; the marker differs for every method too, so two
methods never look alike even where two light colours are close. Figures are bare
``matplotlib.figure.Figure`` objects rendered by the Agg canvas: no pyplot state, no window.
"""

from __future__ import annotations

import zlib
from pathlib import Path

from matplotlib.figure import Figure

from magbench.core.files import atomic_path

__all__ = ["METHOD_STYLE", "MethodStyle", "method_style", "new_figure", "save_figure"]

DPI = 110

#: (colour, marker) of every method magbench ships, in display order: the review's seven
#: (Okabe-Ito), the extra magnetometer methods and the printed variants (Tol muted), the
#: gyro-aided methods (Tol light and muted).
METHOD_STYLE: dict[str, tuple[str, str]] = {
    "twostep": ("#E69F00", "o"), "crassidis": ("#56B4E9", "s"),
    "dorveaux": ("#009E73", "^"), "vasconcelos": ("#0072B2", "D"),
    "ali": ("#D55E00", "v"), "wu_shi": ("#CC79A7", "P"), "magical": ("#000000", "X"),
    "wu_shi_nm": ("#882255", "<"), "ellipsoid": ("#332288", ">"), "fang": ("#117733", "h"),
    "sphere": ("#999933", "*"), "twostep_hi": ("#DDCC77", "p"),
    "vasconcelos_printed": ("#88CCEE", "d"), "wu_shi_printed": ("#AA4499", "8"),
    # Table 2's hypotheses (Tol dark teal, a neutral grey; unfilled markers used nowhere else)
    "twostep_no_svd": ("#225555", "x"), "crassidis_prior": ("#555555", "+"),
    "sar_ls": ("#CC6677", "H"), "sar_kf": ("#44AA99", "o"), "sar_aid": ("#EE8866", "s"),
    "magyc_ls": ("#77AADD", "^"), "magyc_nls": ("#BBCC33", "D"), "magyc_bfg": ("#FFAABB", "v"),
    "magyc_ifg": ("#99DDFF", "P"), "magfactor3": ("#AAAA00", "X"),
    "diagonal": ("#44BB99", "8"), "als": ("#6699CC", ">"),
    # the magnetometer-to-IMU alignment methods (earth tones)
    "dip_align": ("#774411", "d"), "magical_aligned": ("#555599", "X"),
    "mag_imu_map": ("#AA7744", "H"),
}
#: Line style and width by family: the review's methods solid and heavier.
FAMILY_LINE = {"review": ("-", 1.8), "extra": ("--", 1.2), "variant": ("-.", 1.2),
               "gyro": (":", 1.4)}
_SPARE_MARKERS = "os^Dv<>hpd"
#: Colours for methods without a fixed entry (Paul Tol's "vibrant" and "bright" schemes, none
#: of which is in METHOD_STYLE), combined with a marker so every such method differs.
_SPARE_COLOURS = ("#EE7733", "#0077BB", "#EE3377", "#CC3311", "#009988", "#4477AA",
                  "#228833", "#CCBB44", "#EE6677", "#AA3377", "#33BBEE", "#BBBBBB")


def _spare_index(name: str) -> int:
    """A stable index for a method outside METHOD_STYLE.

    Registered methods without a fixed entry are numbered in name order, so no two of them
    share a (colour, marker) pair and the number does not depend on the figure; a name that
    is not registered (a method of an older run) is placed by its CRC-32 after them.
    """
    try:
        from magbench.methods.registry import methods

        unstyled = sorted(n for n in methods() if n not in METHOD_STYLE)
    except Exception:      # the registry failed to load: still draw something
        unstyled = []
    if name in unstyled:
        return unstyled.index(name)
    return len(unstyled) + zlib.crc32(name.encode()) % (len(_SPARE_COLOURS) ** 2)


class MethodStyle(dict):
    """Keyword arguments of ``Axes.plot`` for one method (colour, marker, line, label)."""


def method_style(name: str) -> MethodStyle:
    """The fixed style of ``name``: colour, marker, line style and width, and its label.

    A method that is not in :data:`METHOD_STYLE` (a new variant, a plugin, or one of an older
    run) gets a spare colour and marker (:func:`_spare_index`), the same in every figure and
    distinct from every other registered method's.
    """
    # Here, not at import: calibrate's picture process draws no method and starts faster.
    from magbench.methods.registry import find_method

    spec = find_method(name)
    label = name if spec is None else spec.label
    family = "extra" if spec is None else "gyro" if spec.needs_gyro else spec.family
    if name in METHOD_STYLE:
        colour, marker = METHOD_STYLE[name]
    else:
        k = _spare_index(name)
        colour = _SPARE_COLOURS[k % len(_SPARE_COLOURS)]
        marker = _SPARE_MARKERS[(k // len(_SPARE_COLOURS) + k) % len(_SPARE_MARKERS)]
    linestyle, width = FAMILY_LINE.get(family, FAMILY_LINE["extra"])
    return MethodStyle(color=colour, marker=marker, linestyle=linestyle, linewidth=width,
                       markersize=5, label=label)


def new_figure(width: float, height: float, **kwargs: object) -> Figure:
    """A bare Figure with the constrained layout every magbench figure uses (``layout=None``
    for a figure that places its axes itself)."""
    return Figure(figsize=(width, height), **{"layout": "constrained", **kwargs})


def save_figure(fig: Figure, path: Path | str, dpi: int = DPI,
                compress_level: int | None = None) -> Path:
    """Render ``fig`` to PNG at ``path`` atomically (temporary file, then rename).

    ``compress_level`` is zlib's, 0-9 (None: Pillow's default, 6); lower is faster and larger,
    with the same pixels.
    """
    path = Path(path)
    extra = {} if compress_level is None else {"pil_kwargs": {"compress_level": compress_level}}
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png", **extra)
    return path
