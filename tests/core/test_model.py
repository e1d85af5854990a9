import numpy as np
import pytest

from magbench.core.model import Calibration, as_samples


def test_apply_inverts_the_model():
    rng = np.random.default_rng(0)
    T = np.eye(3) + 0.1 * rng.standard_normal((3, 3))
    h = rng.standard_normal(3)
    m = rng.standard_normal((50, 3))
    cal = Calibration(T, h)
    np.testing.assert_allclose(cal.apply(m @ T.T + h), m, atol=1e-12)


def test_correction_is_the_firmware_form_in_the_safe_gauge():
    T = np.array([[1.1, 0.1, 0.0], [0.0, 0.9, 0.2], [0.05, 0.0, 1.0]])
    h = np.array([0.3, -0.2, 0.1])
    A, b = Calibration(T, h).correction()
    y = np.array([[0.5, 0.2, -0.7], [1.0, -1.0, 0.3]])
    np.testing.assert_array_equal(b, h)
    np.testing.assert_allclose(np.linalg.norm((y - b) @ A.T, axis=1),
                               np.linalg.norm(Calibration(T, h).apply(y), axis=1), atol=1e-14)
    np.testing.assert_allclose((y - b) @ A.T, Calibration(T, h).safe().apply(y), atol=1e-14)


def test_apply_takes_a_single_sample():
    cal = Calibration(np.diag([2.0, 4.0, 5.0]), [1.0, 2.0, 3.0])
    out = cal.apply(np.array([3.0, 6.0, 8.0]))
    assert out.shape == (3,)
    np.testing.assert_allclose(out, [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(cal.apply([[3.0, 6.0, 8.0]]), out[None, :])
    with pytest.raises(ValueError, match=r"shape \(K, 3\)"):
        cal.apply(np.zeros(2))


def test_calibration_is_immutable_and_shape_checked():
    cal = Calibration(np.eye(3), np.zeros(3))
    with pytest.raises(ValueError):
        cal.T[0, 0] = 2.0
    with pytest.raises(ValueError, match=r"shape \(3, 3\)"):
        Calibration(np.eye(2), np.zeros(3))


def test_is_finite_flags_nan_and_singular():
    assert Calibration(np.eye(3), np.zeros(3)).is_finite
    assert not Calibration(np.eye(3), [np.nan, 0, 0]).is_finite
    assert not Calibration(np.diag([1.0, 1.0, 0.0]), np.zeros(3)).is_finite


@pytest.mark.parametrize(("smallest", "finite"), [(1.0, True), (1e-6, True), (2e-12, True),
                                                  (5e-13, False), (1e-13, False)])
def test_is_finite_is_the_condition_number_rule(smallest, finite):
    """cond(T) < 1e12, whichever of the scalar bound and np.linalg.cond decides."""
    rng = np.random.default_rng(0)
    Q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    T = Q @ np.diag([1.0, 0.5, smallest])
    assert Calibration(T, np.zeros(3)).is_finite is finite
    assert Calibration(T, [0.0, np.inf, 0.0]).is_finite is False


@pytest.mark.parametrize(
    ("samples", "message"),
    [
        (np.zeros((5, 2)), r"shape \(K, 3\).*got shape \(5, 2\)"),
        (np.zeros(3), r"got shape \(3,\)"),
        ([["a", "b", "c"]], "numeric"),
        (np.zeros((2, 3)), "K=2 rows; at least 4"),
        (np.array([[1.0, 2, 3]] * 4 + [[np.nan, 0, 0]]), r"NaN or infinite values in 1 row\(s\) "
                                                          r"\(rows 4\)"),
    ],
)
def test_as_samples_rejects_bad_input(samples, message):
    with pytest.raises(ValueError, match=message):
        as_samples(samples, min_samples=4)


def test_as_samples_copies():
    y = np.ones((4, 3))
    out = as_samples(y)
    out[0, 0] = 5
    assert y[0, 0] == 1
