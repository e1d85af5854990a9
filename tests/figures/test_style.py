"""One fixed style per method, valid and distinct, the same in every figure."""

from __future__ import annotations

from matplotlib.colors import is_color_like

from magbench.figures.style import METHOD_STYLE, method_style
from magbench.methods.registry import get_method, methods, register, unregister


def test_every_registered_method_has_its_own_colour_and_marker():
    assert set(methods()) <= set(METHOD_STYLE), "a shipped method has no fixed style"
    pairs = [(method_style(m)["color"], method_style(m)["marker"]) for m in methods()]
    assert len(set(pairs)) == len(pairs)
    colours = [p[0] for p in pairs]
    assert len(set(colours)) == len(colours)          # 22 distinct colours
    assert all(is_color_like(c) for c in colours)


def test_style_follows_the_family_and_is_stable():
    assert method_style("magical")["linestyle"] == "-"           # the review's: solid
    assert method_style("fang")["linestyle"] == "--"              # extra methods: dashed
    assert method_style("magyc_nls")["linestyle"] == ":"          # gyro-aided: dotted
    assert method_style("magical")["label"] == get_method("magical").label
    assert method_style("dorveaux") == method_style("dorveaux")


def test_an_unknown_method_gets_a_valid_style_of_its_own():
    style = method_style("someone_elses_method")
    assert is_color_like(style["color"]) and style["label"] == "someone_elses_method"
    assert style == method_style("someone_elses_method")
    assert style["color"] not in {c for c, _ in METHOD_STYLE.values()}


def test_registered_methods_without_a_fixed_entry_get_distinct_styles():
    names = [f"zz_variant_{i}" for i in range(15)]
    for name in names:
        register(name, label=name, min_samples=4, family="variant")(lambda samples: None)
    try:
        pairs = {(method_style(n)["color"], method_style(n)["marker"]) for n in names}
        fixed = {(method_style(n)["color"], method_style(n)["marker"]) for n in METHOD_STYLE}
        assert len(pairs) == len(names) and not pairs & fixed
        assert method_style("zz_variant_3") == method_style("zz_variant_3")
    finally:
        for name in names:
            unregister(name)


def test_save_figure_compression_changes_the_size_not_the_pixels(tmp_path):
    import matplotlib.image as mpimg
    import numpy as np

    from magbench.figures.style import new_figure, save_figure

    fig = new_figure(4, 3)
    ax = fig.add_subplot()
    ax.plot(np.random.default_rng(0).standard_normal((500, 2)), ".")
    ax.set_title("compression")
    default = save_figure(fig, tmp_path / "default.png", dpi=80)
    fast = save_figure(fig, tmp_path / "fast.png", dpi=80, compress_level=1)
    assert np.array_equal(mpimg.imread(default), mpimg.imread(fast))
    assert fast.stat().st_size > default.stat().st_size
