import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from magbench.core.metrics import (
    accuracy_cost,
    procrustes_rotation,
    real_cost,
    summarize,
    trivial_cost,
    trivial_estimate,
)


def random_orthogonal(seed: int, reflect: bool) -> np.ndarray:
    Q = Rotation.random(random_state=seed).as_matrix()
    return Q @ np.diag([1.0, 1.0, -1.0]) if reflect else Q


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 10_000), reflect=st.booleans())
def test_J_is_invariant_to_T_times_orthogonal(seed, reflect):
    rng = np.random.default_rng(seed)
    T_true = np.eye(3) + 0.3 * rng.uniform(-1, 1, (3, 3))
    h_true = rng.uniform(-1, 1, 3)
    T = T_true + 0.01 * rng.standard_normal((3, 3))
    h = h_true + 0.01 * rng.standard_normal(3)
    Q = random_orthogonal(seed, reflect)
    np.testing.assert_allclose(accuracy_cost(T @ Q, h, T_true, h_true),
                               accuracy_cost(T, h, T_true, h_true), rtol=1e-9, atol=1e-13)
    # ... and an exact answer up to rotation costs nothing.
    assert accuracy_cost(T_true @ Q, h_true, T_true, h_true)[0] < 1e-12


def test_procrustes_recovers_the_rotation():
    T_true = np.diag([1.0, 2.0, 3.0])
    Q = random_orthogonal(3, reflect=False)
    np.testing.assert_allclose(procrustes_rotation(T_true @ Q, T_true), Q, atol=1e-12)


def test_J_parts_on_a_hand_made_case():
    # T differs from T_true = I by a diagonal scale: the best orthogonal R is I.
    J, J_h, J_T = accuracy_cost(np.diag([1.1, 1.0, 1.0]), [0.3, 0.4, 0.0], np.eye(3), np.zeros(3))
    assert J_h == pytest.approx(0.5)
    assert J_T == pytest.approx(0.1)
    assert J == pytest.approx(0.6)


def test_trivial_cost():
    # T_true = 2 R0 for a rotation R0: the best alignment of I leaves ||I - 2 I||_F = sqrt(3).
    R0 = random_orthogonal(5, reflect=False)
    assert trivial_cost(2 * R0, [0.0, 3.0, 4.0]) == pytest.approx(5 + np.sqrt(3))


def test_real_cost_zero_on_the_sphere_and_known_value():
    m = Rotation.random(40, random_state=1).apply([1.0, 0, 0])
    T = np.diag([2.0, 1.0, 1.0])
    h = np.array([0.1, 0.2, 0.3])
    assert real_cost(m @ T.T + h, T, h) < 1e-28
    # every ||m_k|| = 2 gives (4 - 1)^2 = 9
    assert real_cost(2 * m @ T.T + h, T, h) == pytest.approx(9.0)


def test_summarize_counts_only_meaningful_runs():
    df = pd.DataFrame({
        "algorithm": ["a"] * 4 + ["b"] * 2,
        "meaningful": [True, True, False, True, False, False],
        "J": [1.0, 3.0, 100.0, 2.0, 5.0, 6.0],
        "time_s": [0.1, 0.3, 9.0, 0.2, 1.0, 1.0],
    })
    s = summarize(df, ["algorithm"]).set_index("algorithm")
    assert s.loc["a", "RB_pct"] == 75.0
    assert s.loc["a", "rho"] == pytest.approx(2.0)
    assert s.loc["a", "accuracy"] == pytest.approx(0.5)
    assert s.loc["a", "tau_s"] == pytest.approx(0.2)
    assert s.loc["a", "speed_hz"] == pytest.approx(5.0)
    assert s.loc["b", "RB_pct"] == 0.0 and np.isnan(s.loc["b", "rho"])
    assert s.loc["b", "n"] == 2 and s.loc["b", "n_meaningful"] == 0


def test_trivial_estimate_is_mean_and_mean_distance_with_its_real_cost():
    y = np.array([[3.0, 1, 0], [-1, 1, 0], [1, 3, 0], [1, -1, 0], [1, 1, 3], [1, 1, -3]])
    T, h, J = trivial_estimate(y)
    r = 14.0 / 6.0                          # distances 2, 2, 2, 2, 3, 3 from the mean
    assert np.allclose(h, [1.0, 1.0, 0.0]) and np.allclose(T, r * np.eye(3))
    assert J == pytest.approx(real_cost(y, T, h), rel=1e-12)
    centred = y - h
    assert trivial_estimate(y, h, centred)[2] == J
