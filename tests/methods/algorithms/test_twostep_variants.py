"""TWOSTEP with steps 9-10 skipped (issue 14's hypothesis (a)): known answers from E* and c*."""

from __future__ import annotations

import numpy as np
import pytest

import magbench
from magbench.core.geometry import fibonacci_sphere
from magbench.methods.algorithms import twostep_variants

D_KNOWN = np.array([[0.10, 0.02, -0.03],
                    [0.02, -0.05, 0.01],
                    [-0.03, 0.01, 0.08]])
H_KNOWN = np.array([0.04, -0.02, 0.03])
T_KNOWN = np.linalg.inv(np.eye(3) + D_KNOWN)
#: The auxiliary quantities of section 3: E = 2D + D^2, c = (I + D) b with h = (I + D)^-1 b.
E_KNOWN = 2.0 * D_KNOWN + D_KNOWN @ D_KNOWN
C_KNOWN = (np.eye(3) + D_KNOWN) @ (np.eye(3) + D_KNOWN) @ H_KNOWN


def test_noise_free_data_give_the_formula_on_the_constructed_E_star():
    # Noise-free y = (I + D)^-1 m + h; TWOSTEP's E* is E_KNOWN, so D* = E* must give
    # T = (I + E*)^-1 and, by (14b)-(15) as printed, h = (I + E*)^-1 c*.
    y = fibonacci_sphere(300) @ T_KNOWN.T + H_KNOWN
    cal = magbench.calibrate(y, "twostep_no_svd", sigma=1e-9)
    inv = np.linalg.inv(np.eye(3) + E_KNOWN)
    np.testing.assert_allclose(cal.T, inv, atol=1e-9)
    np.testing.assert_allclose(cal.h, inv @ C_KNOWN, atol=1e-9)
    # The formula is the square of the right T; the bias in model (2)'s convention is T' h.
    np.testing.assert_allclose(cal.T, T_KNOWN @ T_KNOWN, atol=1e-9)
    model = magbench.calibrate(y, "twostep_no_svd", sigma=1e-9, bias="model")
    np.testing.assert_allclose(model.h, inv @ inv @ C_KNOWN, atol=1e-9)


def test_no_svd_calibration_inverts_the_svd_step_exactly():
    T, h = twostep_variants.no_svd_calibration(T_KNOWN, H_KNOWN, "review")
    np.testing.assert_allclose(np.linalg.inv(T) - np.eye(3), E_KNOWN, atol=1e-14)
    np.testing.assert_allclose(h, H_KNOWN, atol=1e-15)


def test_it_is_a_variant_and_checks_its_bias_option():
    assert magbench.get_method("twostep_no_svd").family == "variant"
    with pytest.raises(ValueError, match="bias must be one of"):
        magbench.calibrate(fibonacci_sphere(50), "twostep_no_svd", bias="other")
