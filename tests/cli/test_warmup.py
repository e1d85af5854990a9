"""``python -m magbench warmup`` and the line a cold numba cache shows before a sweep."""

from __future__ import annotations

from magbench.cli import main
from magbench.engine.warm import compiled_methods, warm_methods


def test_warmup_compiles_the_selected_methods_loops_and_says_so(capsys):
    assert main(["warmup", "algorithms=[sphere,magical,dorveaux]", "progress=false"]) == 0
    err = capsys.readouterr().err
    assert "numba kernels ready for 2 method(s) (magical, dorveaux)" in err


def test_only_methods_with_compiled_loops_are_warmed():
    # The variants are partials of the compiled methods; gyro-aided methods have no data here.
    assert compiled_methods(["sphere", "magical", "crassidis_prior", "fang"]) == [
        "magical", "crassidis_prior"]
    assert warm_methods(["sphere", "fang"]) == 0.0


def test_a_slow_warm_up_shows_its_line_and_bar(capsys):
    """Past ``quiet_s`` the line appears (here at once); with a warm cache and the default
    delay nothing does."""
    warm_methods(["magical"], progress=True, quiet_s=0.0)
    assert "compiling the numba kernels, first run only, ~4 s" in capsys.readouterr().err
    warm_methods(["magical"], progress=True)
    assert capsys.readouterr().err == ""
