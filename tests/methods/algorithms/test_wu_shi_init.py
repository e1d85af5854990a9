"""upper_inverse: the exact 3x3 back substitution of _wu_shi_init."""

import numpy as np
import pytest

from magbench.methods.algorithms._wu_shi_init import upper_inverse


@pytest.mark.parametrize("seed", range(5))
def test_upper_inverse_is_the_inverse_and_upper_triangular(seed):
    rng = np.random.default_rng(seed)
    U = np.triu(rng.normal(size=(3, 3))) + np.diag(rng.uniform(0.5, 2.0, 3))
    X = upper_inverse(U)
    assert np.all(np.tril(X, -1) == 0.0)
    assert np.allclose(X @ U, np.eye(3), atol=1e-14) and np.allclose(X, np.linalg.inv(U))


def test_upper_inverse_known_answer():
    U = np.array([[2.0, 4.0, 8.0], [0.0, 4.0, 2.0], [0.0, 0.0, 0.5]])
    assert np.array_equal(upper_inverse(U), [[0.5, -0.5, -6.0], [0.0, 0.25, -1.0],
                                             [0.0, 0.0, 2.0]])


def test_upper_inverse_refuses_a_zero_diagonal_and_nan():
    with pytest.raises(np.linalg.LinAlgError, match="diagonal 1"):
        upper_inverse(np.diag([1.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match="infs or NaNs"):
        upper_inverse(np.diag([1.0, np.nan, 1.0]))
