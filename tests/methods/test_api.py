import re

import numpy as np
import pytest

import magbench
from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.registry import register, unregister


@pytest.fixture
def temporary_method():
    names = []

    def make(name, fit, **kw):
        register(name, label=name, min_samples=4, **kw)(fit)
        names.append(name)

    yield make
    for n in names:
        unregister(n)


def test_methods_are_in_display_order():
    names = magbench.methods()
    assert names.index("dorveaux") < names.index("magical")


def test_non_finite_answer_is_calibration_failed(temporary_method, nominal):
    temporary_method("nan_method", lambda y: Calibration(np.full((3, 3), np.nan), np.zeros(3)))
    with pytest.raises(CalibrationFailed, match="not finite"):
        magbench.calibrate(nominal.y, "nan_method")


def test_linalg_error_is_calibration_failed(temporary_method, nominal):
    def fit(y):
        return Calibration(np.linalg.cholesky(-np.eye(3)), np.zeros(3))

    temporary_method("chol_method", fit)
    with pytest.raises(CalibrationFailed, match="linear algebra failed"):
        magbench.calibrate(nominal.y, "chol_method")


def test_randomized_methods_get_a_seeded_generator(temporary_method, nominal):
    seen = []

    def fit(y, *, rng=None):
        seen.append(rng.random())
        return Calibration(np.eye(3), np.zeros(3))

    temporary_method("random_method", fit, randomized=True)
    magbench.calibrate(nominal.y, "random_method")
    magbench.calibrate(nominal.y, "random_method")
    magbench.calibrate(nominal.y, "random_method", rng=5)
    assert seen[0] == seen[1] != seen[2]


def test_gyro_methods_need_rates(temporary_method, nominal):
    temporary_method("gyro_method", lambda y, *, angular_rate, time: Calibration(np.eye(3),
                                                                                np.zeros(3)),
                     needs_gyro=True)
    with pytest.raises(ValueError, match="needs angular_rate"):
        magbench.calibrate(nominal.y, "gyro_method")


def test_duplicates_and_zeros_are_rejected(nominal):
    with pytest.raises(ValueError, match="distinct measurements"):
        magbench.calibrate(np.repeat(nominal.y[:2], 10, axis=0), "magical")
    with pytest.raises(ValueError, match="all zero"):
        magbench.calibrate(np.zeros((10, 3)), "magical")
    with pytest.raises(ValueError, match="collinear"):
        magbench.calibrate(np.outer(np.linspace(1, 2, 10), [1.0, 2.0, 3.0]), "magical")


def test_distinct_rows_counts_as_unique_does_and_may_stop_at_enough():
    from magbench.methods.api import _distinct_rows

    rng = np.random.default_rng(3)
    y = np.round(rng.standard_normal((400, 3)), 1)      # many repeated first coordinates
    y = np.vstack([y, y[:50], -0.0 * y[:1] + 0.0])       # repeated rows and a signed zero
    exact = np.unique(y, axis=0).shape[0]
    assert _distinct_rows(y) == exact
    assert _distinct_rows(y, enough=exact + 1) == exact  # not enough: the exact count
    firsts = np.unique(y[:, 0]).size
    assert firsts < exact
    assert _distinct_rows(y, enough=10) == firsts >= 10  # enough: a lower bound, no lexsort
    assert _distinct_rows(np.repeat(y[:3], 4, axis=0), enough=4) == 3


def test_registering_twice_is_an_error():
    with pytest.raises(ValueError, match="registered twice"):
        register("magical", label="x", min_samples=4)(lambda y: None)


def test_the_methods_package_is_callable_and_importable_by_dotted_path():
    import subprocess
    import sys

    code = ("import magbench, sys; names = magbench.methods(); "
            "import magbench.methods.algorithms.wu_shi as w; "
            "from magbench.methods.registry import methods; "
            "print(names == methods(), w.__name__, 'pandas' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    # the list of names, the subpackage by its dotted path, and pandas still not loaded
    assert out == ["True", "magbench.methods.algorithms.wu_shi", "False"]


def rotated_dataset(K: int = 400, seed: int = 3):
    """Samples of y = R S m + h: a soft-iron S seen through a 50 deg rotation R."""
    from scipy.spatial.transform import Rotation

    from magbench.core.geometry import fibonacci_sphere

    R = Rotation.from_rotvec(np.radians(50) * np.array([0.3, -0.8, 0.5]) /
                             np.linalg.norm([0.3, -0.8, 0.5])).as_matrix()
    S = np.array([[1.1, 0.05, -0.02], [0.05, 0.9, 0.03], [-0.02, 0.03, 1.05]])
    h = np.array([0.2, -0.1, 0.05])
    noise = 0.002 * np.random.default_rng(seed).standard_normal((K, 3))
    return fibonacci_sphere(K) @ (R @ S).T + h + noise


MAG_ONLY = [m for m in magbench.methods() if magbench.get_method(m).magnetometer_only]


@pytest.mark.parametrize("name", MAG_ONLY)
def test_every_magnetometer_method_hands_back_the_safe_gauge(name):
    from magbench.core.gauge import symmetric_T

    y = rotated_dataset()
    try:
        raw = magbench.calibrate(y, name, raw=True)
    except CalibrationFailed:
        pytest.skip(f"{name} fails on these data (a printed variant)")
    cal = magbench.calibrate(y, name)
    np.testing.assert_array_equal(cal.T, cal.T.T)
    assert np.linalg.eigvalsh(cal.T).min() > 0 and np.linalg.det(cal.T) > 0
    np.testing.assert_allclose(cal.T, symmetric_T(raw.T), rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(cal.h, raw.h)
    assert (cal.n_iter, cal.converged, cal.message) == (raw.n_iter, raw.converged, raw.message)
    # Only the rotation is removed: the corrected field has the method's own magnitudes.
    np.testing.assert_allclose(np.linalg.norm(cal.apply(y), axis=1),
                               np.linalg.norm(raw.apply(y), axis=1), rtol=1e-9)


def test_the_raw_output_of_some_methods_is_rotated_or_mirrored():
    # Why the gauge is needed: these return T up to an orthogonal factor (det < 0: a mirror).
    y = rotated_dataset()
    raw = {m: magbench.calibrate(y, m, raw=True).T for m in ("vasconcelos", "dorveaux",
                                                             "magical", "wu_shi")}
    assert any(not np.allclose(T, T.T, atol=1e-6) for T in raw.values())


@pytest.mark.parametrize("case", ["good", "coplanar", "few", "nan", "duplicates"])
def test_checked_samples_give_every_method_the_answer_and_error_of_a_plain_call(case, nominal):
    """Samples checked once (CheckedSamples) for methods of every kind of check (full, sphere,
    bias-only): the same estimate, bit for bit, or the same ValueError as a plain call."""
    from magbench.methods.api import CheckedSamples, calibrate

    y = nominal.y[:60].copy()
    if case == "coplanar":
        y[:, 2] = 0.5
    elif case == "few":
        y = y[:7]
    elif case == "nan":
        y[3, 1] = np.nan
    elif case == "duplicates":
        y = np.repeat(y[:6], 10, axis=0)
    names = ["fang", "sphere", "magical", "ellipsoid"]
    checked = CheckedSamples(y).prepare_for(names)
    for name in names:
        try:
            plain = calibrate(y, name, raw=True)
        except ValueError as exc:
            with pytest.raises(ValueError, match=f"^{re.escape(str(exc))}$"):
                calibrate(checked, name, raw=True)
            continue
        assert case in ("good", "few", "duplicates")
        once = calibrate(checked, name, raw=True)
        assert np.array_equal(once.T, plain.T) and np.array_equal(once.h, plain.h)
        assert (once.converged, once.message, once.n_iter) == (plain.converged, plain.message,
                                                               plain.n_iter)
