"""The lazy numba import of methods/algorithms/_jit.py, checked in fresh interpreters."""

import os
import subprocess
import sys

import magbench


def run_fresh(code: str, cwd: str | None = None) -> str:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True, cwd=cwd)
    return out.stdout.split()


def test_registering_the_methods_imports_neither_numba_nor_scipy():
    names, numba, scipy = run_fresh(
        "import sys\n"
        "from magbench.methods import methods\n"
        "names = methods()\n"
        "print(len(names), 'numba' in sys.modules, 'scipy' in sys.modules)")
    assert int(names) == len(magbench.methods()) and numba == "False" and scipy == "False"


def test_a_compiled_loop_calling_another_works_after_the_lazy_import():
    """Dorveaux's compiled loop calls _common.fit_affine: before the first call both are
    placeholders; after it both names are numba dispatchers and the fit is exact on
    noise-free data."""
    before, after, J = run_fresh(
        "import sys, numpy as np\n"
        "from magbench.methods.algorithms import dorveaux, _jit\n"
        "from magbench.core.metrics import accuracy_cost\n"
        "from magbench.sources.synthetic import Point, make_dataset\n"
        "d = make_dataset(np.random.default_rng(3), Point(K=300, sigma=0.0))\n"
        "before = isinstance(dorveaux.fit_affine, _jit.LazyLoop) and 'numba' not in sys.modules\n"
        "cal = dorveaux.fit(d.y)\n"
        "from numba.core.dispatcher import Dispatcher\n"
        "after = isinstance(dorveaux.fit_affine, Dispatcher) and isinstance(dorveaux.iterate,"
        " Dispatcher)\n"
        "print(before, after, accuracy_cost(cal.T, cal.h, d.T, d.h)[0])")
    assert before == "True" and after == "True"
    assert float(J) < 1e-6


def test_prepare_loads_numba_for_a_compiled_method_only():
    """What the engine calls before timing a call: a closed form loads nothing, a compiled
    method (here a printed variant, registered as a partial) loads numba and rebinds every
    placeholder, so that its callees are dispatchers before any thread compiles."""
    closed, compiled, rebound = run_fresh(
        "import sys\n"
        "from magbench.methods.registry import get_method\n"
        "get_method('fang').prepare()\n"
        "closed = 'numba' in sys.modules\n"
        "get_method('wu_shi_printed').prepare()\n"
        "from magbench.methods.algorithms import _common, _jit\n"
        "print(closed, 'numba' in sys.modules, not isinstance(_common.fit_affine, _jit.LazyLoop))")
    assert (closed, compiled, rebound) == ("False", "True", "True")


def test_a_folder_named_coverage_in_the_working_directory_does_not_break_numba(tmp_path):
    """``results/`` holds a ``coverage`` folder: run from there, numba took it for coverage.py
    (an empty namespace package) and its import failed. The folder stays importable after."""
    (tmp_path / "coverage").mkdir()
    loaded, folder = run_fresh(
        "import sys\n"
        "from magbench.methods.algorithms import _jit\n"
        "_jit.load()\n"
        "import coverage\n"
        "print('numba' in sys.modules, getattr(coverage, '__file__', None) is None)",
        cwd=str(tmp_path))
    assert (loaded, folder) == ("True", "True")
