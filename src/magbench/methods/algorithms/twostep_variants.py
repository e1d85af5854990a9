"""Hypotheses for the review's TWOSTEP accuracy (Table 2: 35.3, RB 91.6 %), as variants.

Implemented as review Algorithm 1 describes it (:mod:`.twostep`), TWOSTEP is as accurate as the
other full methods (squared-form 1/rho ~2.5e5 at the nominal point, on the Cramer-Rao floor).
The review's 35.3 in the squared form it uses (1/mean(J_h^2 + J_T^2), see results/report.md)
is an RMS error of ~0.17, hardly better than no calibration at all (~21): the overall scale of
T was not recovered. Two readings of the review's text give that magnitude:

(a) ``twostep_no_svd`` (registered here): Steps 9-10 of Algorithm 1 skipped. The estimation
    vector theta' holds the *auxiliary* ``E = 2D + D^2`` and ``c = (I + D) h`` ("TWOSTEP
    algorithm functions on ... the auxiliary parameters, E and c and not on the actual
    calibration parameters, D and h", section 3), and the conversion back is a separate,
    easily-missed step: the SVD of E* (13), ``W`` with ``S = 2W + W^2`` and ``D* = U W U^T``
    (14a). Reading E* as D* gives ``T = (I + E*)^-1 = (I + D)^-2``, the square of the right
    T: every scale error doubles. With ``D* = E*`` also in (14b), ``h* = (I + E*)^-1 c*``, and
    (15) as printed, ``h = h*``.
(b) bias only, ``T = I``: the paper named "TWOSTEP" is the review's reference [18], Alonso and
    Shuster's *attitude-independent magnetometer-bias determination*; section 3 says the
    authors "initially solved the problem of bias, h, determination ... and then extended
    their method to determine matrix T as well [1]". Running the bias-only TWOSTEP leaves
    ``T = I``. That method is already registered as ``twostep_hi`` (``T = field_norm I``, with
    ``field_norm = 1`` on the review's data): it *is* hypothesis (b), so it is not registered
    a second time.

Neither is proven; ``magbench.report.variants`` sets both beside Table 2.
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration
from magbench.methods.algorithms import twostep
from magbench.methods.algorithms._twostep_model import BIAS_CONVENTIONS
from magbench.methods.registry import register


def no_svd_calibration(T: np.ndarray, h: np.ndarray, bias: str = "review"
                       ) -> tuple[np.ndarray, np.ndarray]:
    """``T`` and ``h`` with ``D* = E*`` in (14)-(15), from TWOSTEP's ``T = (I + D*)^-1`` and
    model bias ``h = (I + D*)^-1 b*``.

    TWOSTEP's D* satisfies ``(I + D*)^2 = I + E*`` exactly (13)-(14a): ``D* = U W U^T`` with
    ``(1 + w_j)^2 = 1 + s_j``. So E* and c* are recovered from its output without running the
    iteration again: ``I + E* = T^-2`` and ``c* = (I + D*) b* = T^-1 T^-1 h`` (``b* = T^-1 h``).
    Then ``D* = E*`` gives

        T' = (I + E*)^-1 = T^2,     h*' = (I + E*)^-1 c* = T^2 T^-2 h = h   (14b),

    and ``h' = h*'`` by (15) as printed (``bias="review"``) or ``h' = T' h*'`` (model (2),
    ``bias="model"``).
    """
    if bias not in BIAS_CONVENTIONS:
        raise ValueError(f"bias must be one of {BIAS_CONVENTIONS}, got {bias!r}")
    T_no_svd = T @ T                      # (I + E*)^-1 = ((I + D*)^-1)^2
    h_star = np.array(h, dtype=float)     # (I + E*)^-1 c*, see above
    return T_no_svd, (T_no_svd @ h_star if bias == "model" else h_star)


@register("twostep_no_svd", label="TWOSTEP (D* = E*, steps 9-10 skipped)", min_samples=10,
          family="variant")
def fit(samples: np.ndarray, *, sigma: float = 0.005, tol: float = 1e-10, max_iter: int = 50,
        bias: str = "review") -> Calibration:
    """TWOSTEP with the conversion of steps 9-10 ((13)-(14a)) skipped: ``T = (I + E*)^-1``.

    Hypothesis (a) of the module docstring. Steps 1-8 (eqs. (4)-(12)) are TWOSTEP's
    (:func:`magbench.methods.algorithms.twostep.fit`, whose estimate determines E* and c*
    exactly, see :func:`no_svd_calibration`); then ``D* = E*``.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k`` near unit field magnitude.
    sigma, tol, max_iter
        As for ``twostep``.
    bias : {"review", "model"}
        ``"review"`` (default): ``h = h* = (I + E*)^-1 c*``, (14b) and (15) as printed with
        ``D* = E*``; ``"model"``: ``h = (I + E*)^-1 h*``, model (2)'s convention.

    Returns
    -------
    Calibration
        ``T = (I + E*)^-1``. Fails where TWOSTEP fails, including ``I + E*`` not positive
        definite, where skipping the SVD would give an indefinite T (never at the nominal point).
    """
    if bias not in BIAS_CONVENTIONS:
        raise ValueError(f"bias must be one of {BIAS_CONVENTIONS}, got {bias!r}")
    cal = twostep.fit(samples, sigma=sigma, tol=tol, max_iter=max_iter, bias="model")
    T, h = no_svd_calibration(cal.T, cal.h, bias)
    return Calibration(T, h, cal.n_iter, cal.converged, f"D* = E* (no SVD); {cal.message}")
