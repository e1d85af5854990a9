"""Model-based 95 % intervals on a calibration's ``h`` and ``A`` from the Fisher information.

At the estimate ``T, h`` of ``y_k = T m_k + h + e_k`` (eq. 67) with ``e_k ~ N(0, sigma^2 I)``:

* the directions are ``m_k = u_k / ||u_k||``, ``u_k = T^-1 (y_k - h)``;
* the noise is estimated from the distance of each sample to the fitted ellipsoid along its
  normal, ``d_k = (||u_k|| - 1) / ||T^-T m_k||`` (the one residual component that carries
  information, :mod:`magbench.core.crb`), as ``sigma^2 = sum_k d_k^2 / (K - p)`` with p the
  model's free parameters;
* the covariance of ``(vec T, h)`` is the inverse Fisher information within the method's model
  (:func:`magbench.core.crb.parameter_covariance`), and that of the gauge's
  ``A = (T T^T)^(-1/2)`` follows by the delta method, ``J C J^T`` with J the derivative of
  ``vec A`` with respect to ``vec T`` (central differences; A does not depend on the rotation
  the full model cannot fix, so neither does its interval).

The intervals are ``estimate +- 1.96 sqrt(variance)``: model-based, exact only as far as the
noise is independent, Gaussian and isotropic and the model holds. Real noise is correlated in
time (a slow rotation, a drifting offset, a model error that follows the rotation), so
``calibrate`` also refits on *block* resamples of the recording (:func:`block_resample`, blocks
:data:`BLOCK_FACTOR` times the residuals' integrated correlation time,
:func:`correlation_length`) and reports the wider interval of the two.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from magbench.core.crb import MODEL_PARAMETERS, parameter_covariance
from magbench.core.gauge import safe_gauge

__all__ = ["BLOCK_FACTOR", "MIN_BLOCKS", "WINDOW", "Intervals", "a_jacobian", "block_length",
           "block_resample", "correlation_length", "fisher_intervals", "noise_sigma",
           "student_t95"]

Z95 = 1.959963984540054


@dataclass(frozen=True)
class Intervals:
    """Model-based 95 % intervals of a calibration in the safe gauge.

    Attributes
    ----------
    h, h_half : ndarray, shape (3,)
        The offset and the half-widths of its intervals (recording units).
    A, A_half : ndarray, shape (3, 3)
        ``A = (T T^T)^(-1/2)`` and the half-widths of its entries.
    sigma : float
        Estimated noise standard deviation (recording units).
    model : str
        The model whose information was used.
    """

    h: np.ndarray
    h_half: np.ndarray
    A: np.ndarray
    A_half: np.ndarray
    sigma: float
    model: str

    def to_dict(self) -> dict:
        return {"h": self.h.tolist(), "h_half_width": self.h_half.tolist(),
                "A": self.A.tolist(), "A_half_width": self.A_half.tolist(),
                "sigma": self.sigma, "model": self.model, "level": 0.95,
                "kind": "model-based: inverse Fisher information at the estimate, "
                        "independent Gaussian noise assumed"}


def _directions(y: np.ndarray, T: np.ndarray, h: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    u = np.linalg.solve(T, (y - h).T).T
    rho = np.sqrt(np.einsum("ij,ij->i", u, u))
    m = u / rho[:, None]
    n = np.linalg.solve(T.T, m.T).T
    return m, rho, np.sqrt(np.einsum("ij,ij->i", n, n))


def noise_sigma(y: np.ndarray, T: np.ndarray, h: np.ndarray, n_params: int) -> float:
    """``sqrt(sum_k d_k^2 / (K - p))`` with ``d_k`` the distance along the normal (notes)."""
    _, rho, n_norm = _directions(np.asarray(y, float), np.asarray(T, float),
                                 np.asarray(h, float))
    d = (rho - 1.0) / n_norm
    return float(np.sqrt(np.sum(d * d) / max(len(d) - n_params, 1)))


def a_jacobian(T: np.ndarray) -> np.ndarray:
    """``d vec(A) / d vec(T)`` (9 x 9, row-major vec) of ``A = (T T^T)^(-1/2)``."""
    T = np.asarray(T, dtype=float)
    step = 1e-6 * float(np.linalg.norm(T))
    J = np.empty((9, 9))
    for k in range(9):
        dT = np.zeros(9)
        dT[k] = step
        plus = safe_gauge(T + dT.reshape(3, 3), np.zeros(3)).A
        minus = safe_gauge(T - dT.reshape(3, 3), np.zeros(3)).A
        J[:, k] = (plus - minus).ravel() / (2.0 * step)
    return J


def fisher_intervals(y: np.ndarray, T: np.ndarray, h: np.ndarray,
                     model: str = "full") -> Intervals:
    """95 % intervals on ``h`` and the entries of ``A`` (see the module notes).

    Parameters
    ----------
    y : ndarray, shape (K, 3)
        The samples the calibration was fitted on (outliers removed).
    T, h : ndarray
        The estimate, in any gauge.
    model : str
        ``full``, ``diagonal``, ``sphere`` or ``bias``: the parameters the method estimated.

    Returns
    -------
    Intervals
        Infinite half-widths when the directions do not determine the parameters.
    """
    y, T, h = (np.asarray(a, dtype=float) for a in (y, T, h))
    m, _, _ = _directions(y, T, h)
    sigma = noise_sigma(y, T, h, MODEL_PARAMETERS[model])
    C = parameter_covariance(T, m, sigma, model)
    A = safe_gauge(T, h).A
    if not np.all(np.isfinite(C)):
        inf = np.full(3, np.inf)
        return Intervals(h, inf, A, np.full((3, 3), np.inf), sigma, model)
    J = a_jacobian(T)
    var_A = np.einsum("ij,jk,ik->i", J, C[:9, :9], J)
    return Intervals(h, Z95 * np.sqrt(np.diag(C)[9:]), A,
                     Z95 * np.sqrt(np.clip(var_A, 0, None)).reshape(3, 3), sigma, model)


#: The block bootstrap's blocks are this many times the residuals' correlation time ...
BLOCK_FACTOR = 5.0
#: ... and no longer than the recording over this many blocks (enough blocks to resample).
MIN_BLOCKS = 8
#: Sokal's window: the autocorrelations are summed up to the first lag M >= WINDOW * tau(M).
WINDOW = 5.0


def correlation_length(residuals: np.ndarray) -> float:
    """Integrated autocorrelation time of the residuals, in samples.

    ``tau = 1 + 2 sum_(k=1..M) rho(k)`` with Sokal's automatic window, the first ``M`` with
    ``M >= 5 tau(M)`` (Sokal 1997; the usual choice for Markov-chain output): 1 for white noise,
    ``(1 + phi) / (1 - phi)`` for AR(1) noise ``e_k = phi e_(k-1) + w_k``; a slow drift,
    whose autocorrelation stays positive over long lags, gives a long time where the lag at
    which the autocorrelation falls below ``1/e`` would not. Computed with the FFT on the
    mean-removed series.
    """
    r = np.asarray(residuals, dtype=float)
    r = r - r.mean()
    n = r.size
    if n < 3 or not np.any(r):
        return 1.0
    spectrum = np.fft.rfft(r, 2 * n)
    acf = np.fft.irfft(spectrum * np.conj(spectrum))[:n]
    tau = 1.0 + 2.0 * np.cumsum(acf[1:] / acf[0])
    window = np.flatnonzero(np.arange(1, n) >= WINDOW * tau)
    return float(max(1.0, tau[window[0]] if window.size else tau[-1]))


def block_length(residuals: np.ndarray) -> int:
    """Block length of :func:`block_resample`: :data:`BLOCK_FACTOR` correlation times,
    at least 1, at most ``K / MIN_BLOCKS``."""
    K = int(np.asarray(residuals).size)
    want = int(np.ceil(BLOCK_FACTOR * correlation_length(residuals)))
    return int(max(1, min(want, K // MIN_BLOCKS)))


def block_resample(K: int, block: int, gen: np.random.Generator) -> np.ndarray:
    """Indices of one circular block-bootstrap resample of ``0..K-1`` (Politis and Romano
    1992): ``ceil(K / block)`` blocks of consecutive indices from random starts, wrapping at
    the end, cut to ``K``."""
    starts = gen.integers(0, K, int(np.ceil(K / block)))
    return ((starts[:, None] + np.arange(block)) % K).ravel()[:K]


def student_t95(dof: float) -> float:
    """Two-sided 95 % quantile of Student's t with ``dof`` degrees of freedom.

    The Cornish-Fisher expansion in ``1 / dof`` about the normal quantile (Abramowitz and
    Stegun 26.7.5, four terms): within 0.2 % of the exact value from 3 degrees of freedom
    (11 % low at 1, 0.8 % at 2; the block bootstrap has at least 7), without importing
    scipy.stats (0.7 s).
    """
    z = Z95
    v = max(float(dof), 1.0)
    g1 = (z**3 + z) / 4
    g2 = (5 * z**5 + 16 * z**3 + 3 * z) / 96
    g3 = (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / 384
    g4 = (79 * z**9 + 776 * z**7 + 1482 * z**5 - 1920 * z**3 - 945 * z) / 92160
    return z + g1 / v + g2 / v**2 + g3 / v**3 + g4 / v**4
