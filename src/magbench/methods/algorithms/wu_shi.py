"""Wu and Shi (2015), optimal maximum likelihood: review section 8, Algorithm 6, eqs. (49)-(57).

The model ``y = T_hat m_hat + h`` (50) has ``T_hat = R^-1`` upper triangular and unit-norm
``m_hat = Q^T m``; the orthogonal ``Q`` is absorbed by the Procrustes alignment of the accuracy
cost (74), so the returned ``Calibration.T`` is ``T_hat``. After the initial estimate (55)-(57),
Newton steps (54) are taken on the Lagrangian (52) with the analytic gradient and Hessian of
Appendix A.2, (A4)-(A7), over ``x = [vec(T_hat) (6 upper entries), h, m_1..m_K, lambda_1..K]``.

The Hessian (A5) is block-arrow: every sample's ``(m_k, lambda_k)`` couples only to the nine
global unknowns. The per-sample 4x4 blocks are eliminated by a Schur complement, solved for all
samples at once, so an iteration costs O(K) instead of the O(K^3) of the (4K+9)-square solve.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from magbench.core.model import Calibration, CalibrationFailed
from magbench.methods.algorithms._common import row_norms
from magbench.methods.algorithms._jit import njit
from magbench.methods.algorithms._wu_shi_init import UPPER_COLS, UPPER_ROWS, initial_estimate
from magbench.methods.registry import register

__all__ = ["State", "fit", "initial_estimate", "lagrangian", "newton_step", "objective",
           "refine"]

#: Largest condition number of the reduced 9x9 system accepted before calling it singular.
MAX_CONDITION = 1e14


@dataclass(frozen=True)
class State:
    """The unknowns x of eq. (53): ``T`` upper triangular, ``h``, ``m (K, 3)``, ``lam (K,)``."""

    T: np.ndarray
    h: np.ndarray
    m: np.ndarray
    lam: np.ndarray


# The Newton step runs as compiled loops over the samples (numba): the gradient, the Hessian
# blocks and the Schur complement are O(K) sums of 3- and 9-vectors, which as NumPy calls cost
# far more in call overhead than in arithmetic. They take the arrays of a State.

_UR, _UC = UPPER_ROWS, UPPER_COLS


@njit
def _residuals(y: np.ndarray, T: np.ndarray, h: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``r_k = u_k - T m_k`` with ``u_k = y_k - h`` (Appendix A.2), shape ``(K, 3)``."""
    K = y.shape[0]
    r = np.empty((K, 3))
    for k in range(K):
        for a in range(3):
            r[k, a] = y[k, a] - h[a] - (m[k, 0] * T[a, 0] + m[k, 1] * T[a, 1]
                                        + m[k, 2] * T[a, 2])
    return r


def _arrays(y: np.ndarray, s: State) -> tuple[np.ndarray, ...]:
    """``y, T, h, m, lam`` as contiguous float arrays, as the compiled functions take them."""
    return tuple(np.ascontiguousarray(a, dtype=np.float64) for a in (y, s.T, s.h, s.m, s.lam))


def residuals(y: np.ndarray, s: State) -> np.ndarray:
    """``r_k = u_k - T m_k`` with ``u_k = y_k - h`` (Appendix A.2), shape ``(K, 3)``."""
    return _residuals(*_arrays(y, s)[:4])


def objective(y: np.ndarray, s: State) -> float:
    """Wu and Shi's ML objective (4) = review (51): ``sum_k ||y_k - T m_k - h||^2``."""
    r = residuals(y, s)
    return float(np.einsum("ij,ij->", r, r))


def lagrangian(y: np.ndarray, s: State, objective_value: float | None = None) -> float:
    """The Lagrange function J(x) of eq. (52).

    ``objective_value``, if given, is ``objective(y, s)`` already computed (refine needs both
    and the objective is most of the cost).
    """
    obj = objective(y, s) if objective_value is None else objective_value
    return obj + float(s.lam @ (np.einsum("ij,ij->i", s.m, s.m) - 1.0))


@njit
def _gradient_from(r: np.ndarray, T: np.ndarray, m: np.ndarray, lam: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`gradient` from the residuals ``r`` of :func:`_residuals`."""
    K = r.shape[0]
    g_g = np.zeros(9)
    g_l = np.empty((K, 4))
    for k in range(K):
        for e in range(6):                                         # J_T (A4)
            g_g[e] += -2.0 * r[k, _UR[e]] * m[k, _UC[e]]
        for a in range(3):                                         # J_h
            g_g[6 + a] += -2.0 * r[k, a]
        for j in range(3):                                         # -2 T^T r_k + 2 lam_k m_k
            g_l[k, j] = -2.0 * (r[k, 0] * T[0, j] + r[k, 1] * T[1, j] + r[k, 2] * T[2, j]) \
                + 2.0 * lam[k] * m[k, j]
        g_l[k, 3] = m[k, 0] ** 2 + m[k, 1] ** 2 + m[k, 2] ** 2 - 1.0
    return g_g, g_l


@njit
def _gradient(y: np.ndarray, T: np.ndarray, h: np.ndarray, m: np.ndarray, lam: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    return _gradient_from(_residuals(y, T, h, m), T, m, lam)


def gradient(y: np.ndarray, s: State) -> tuple[np.ndarray, np.ndarray]:
    """Gradient (A4), (A6): the 9 global entries ``[J_T (upper), J_h]`` and ``(K, 4)`` local ones.

    ``J_T = -2 sum_k m_k kron r_k`` holds ``-2 sum_k r_ka m_kb`` at the entry of ``T_ab``.
    """
    return _gradient(*_arrays(y, s))


@njit
def _coupling(T: np.ndarray, m: np.ndarray, r: np.ndarray, k: int, C: np.ndarray) -> None:
    """Write the T rows of sample k's coupling block ``H_Tm_k`` (A7) into ``C`` (6x3).

    ``H_Tm_k = 2 ((m_k kron I) T - I kron r_k)``: entry ``(T_ab, m_c)`` is
    ``2 m_b T_ac - 2 r_a delta_bc``. The h rows, ``H_hm_k = 2 T``, are the same for every k.
    :func:`_newton` builds it per sample where it is used instead of storing all K blocks:
    a ``(K, 9, 3)`` array's memory traffic cost more than its arithmetic.
    """
    for e in range(6):
        a, b = _UR[e], _UC[e]
        for c in range(3):
            C[e, c] = 2.0 * m[k, b] * T[a, c] - (2.0 * r[k, a] if b == c else 0.0)


@njit
def _global_block(T: np.ndarray, m: np.ndarray) -> np.ndarray:
    """The global block ``[[H_TT, H_Th], [H_Th^T, H_hh]]`` of the Hessian (A5), 9x9."""
    K = m.shape[0]
    mm = np.zeros((3, 3))
    msum = np.zeros(3)
    for k in range(K):
        for b in range(3):
            msum[b] += m[k, b]
            for d in range(3):
                mm[b, d] += m[k, b] * m[k, d]
    A = np.zeros((9, 9))
    for e in range(6):
        for f in range(6):
            # H_TT = 2 sum (m m^T) kron I: entry (T_ab, T_cd) is 2 delta_ac sum m_b m_d.
            if _UR[e] == _UR[f]:
                A[e, f] = 2.0 * mm[_UC[e], _UC[f]]
        # H_Th = 2 sum m kron I: entry (T_ab, h_c) is 2 delta_ac sum m_b.
        A[e, 6 + _UR[e]] = 2.0 * msum[_UC[e]]
        A[6 + _UR[e], e] = A[e, 6 + _UR[e]]
    for a in range(3):
        A[6 + a, 6 + a] = 2.0 * K                                  # H_hh = 2 K I
    return A


@njit
def _hessian_blocks(y: np.ndarray, T: np.ndarray, h: np.ndarray, m: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    K = y.shape[0]
    r = _residuals(y, T, h, m)
    C = np.empty((K, 9, 3))
    Ck = np.empty((6, 3))
    for k in range(K):
        _coupling(T, m, r, k, Ck)
        C[k, :6] = Ck
        for a in range(3):                                         # H_hm_k = 2 T
            for c in range(3):
                C[k, 6 + a, c] = 2.0 * T[a, c]
    return _global_block(T, m), C


def hessian_blocks(y: np.ndarray, s: State) -> tuple[np.ndarray, np.ndarray]:
    """The global and coupling blocks of the Hessian (A5), (A7), lower-triangular T removed.

    The remaining blocks are per sample: ``D_k = [[2 T^T T + 2 lam_k I, 2 m_k], [2 m_k^T, 0]]``
    (``H_{m_k m_k}``, ``H_{m_k lambda_k}``), and the coupling of ``lambda_k`` to the global
    unknowns is zero (A5).

    Returns
    -------
    A : ndarray, shape (9, 9)
        Global block ``[[H_TT, H_Th], [H_Th^T, H_hh]]``.
    C : ndarray, shape (K, 9, 3)
        Coupling of the global unknowns to ``m_k``: ``[H_Tm_k; H_hm_k]``.
    """
    return _hessian_blocks(*_arrays(y, s)[:4])


@njit
def _p_inv(V: np.ndarray, d0: float, d1: float, d2: float, p0: float, p1: float, p2: float
           ) -> tuple[float, float, float]:
    """``P_k^-1 p_k = V diag(d_k) V^T p_k`` for one sample (see :func:`_newton`)."""
    t0 = (p0 * V[0, 0] + p1 * V[1, 0] + p2 * V[2, 0]) * d0
    t1 = (p0 * V[0, 1] + p1 * V[1, 1] + p2 * V[2, 1]) * d1
    t2 = (p0 * V[0, 2] + p1 * V[1, 2] + p2 * V[2, 2]) * d2
    return (t0 * V[0, 0] + t1 * V[0, 1] + t2 * V[0, 2],
            t0 * V[1, 0] + t1 * V[1, 1] + t2 * V[1, 2],
            t0 * V[2, 0] + t1 * V[2, 1] + t2 * V[2, 2])


@njit
def _bordered_solve(V: np.ndarray, d: np.ndarray, w: np.ndarray, inv_gamma: np.ndarray, k: int,
                    p0: float, p1: float, p2: float, q: float
                    ) -> tuple[float, float, float, float]:
    """``[x; mu] = D_k^-1 [p_k; q_k]`` for sample k (see :func:`_newton`)."""
    x0, x1, x2 = _p_inv(V, d[k, 0], d[k, 1], d[k, 2], p0, p1, p2)
    w0, w1, w2 = w[k, 0], w[k, 1], w[k, 2]
    mu = (w0 * p0 + w1 * p1 + w2 * p2 - q) * inv_gamma[k]
    return x0 - w0 * mu, x1 - w1 * mu, x2 - w2 * mu, mu


@njit
def _coupled_step(C: np.ndarray, T2: np.ndarray, dg: np.ndarray, j: int) -> float:
    """Entry j of ``B_k^T dg`` (``m_k`` rows): ``C_k`` (6x3) and the h rows ``2 T``."""
    return (C[0, j] * dg[0] + C[1, j] * dg[1] + C[2, j] * dg[2] + C[3, j] * dg[3]
            + C[4, j] * dg[4] + C[5, j] * dg[5] + T2[0, j] * dg[6] + T2[1, j] * dg[7]
            + T2[2, j] * dg[8])


@njit
def _newton(y: np.ndarray, T: np.ndarray, h: np.ndarray, m: np.ndarray, lam: np.ndarray
            ) -> tuple[int, np.ndarray, np.ndarray]:
    """The step of :func:`newton_step`; status 0, or 1 (singular ``D_k``), 2 (singular S).

    ``D_k^-1`` for all k at once, ``D_k = [[P_k, a_k], [a_k^T, 0]]``, ``P_k = 2 T^T T +
    2 lam_k I``, ``a_k = 2 m_k``: all ``P_k`` share the eigenvectors V of ``T^T T``, so
    ``P_k^-1 = V diag(d_k) V^T`` with ``d_k = 1 / (2 eig(T^T T) + 2 lam_k)``, one 3x3
    eigen-decomposition per iteration instead of K 4x4 solves. With ``w_k = P_k^-1 a_k`` and
    ``gamma_k = a_k^T w_k``, the solution of ``D_k [x; mu] = [p; q]`` is
    ``mu = (w_k^T p - q) / gamma_k``, ``x = P_k^-1 p - w_k mu``.
    """
    K = y.shape[0]
    r = _residuals(y, T, h, m)                  # once, for the gradient and the Hessian
    g_g, g_l = _gradient_from(r, T, m, lam)
    A = _global_block(T, m)
    eigval, V = np.linalg.eigh(T.T @ T)
    # One pass over the samples per stage, each sample's small solves in scalars.
    d = np.empty((K, 3))
    w = np.empty((K, 3))
    inv_gamma = np.empty(K)
    finite = True
    for k in range(K):
        d0 = 1.0 / (2.0 * eigval[0] + 2.0 * lam[k])
        d1 = 1.0 / (2.0 * eigval[1] + 2.0 * lam[k])
        d2 = 1.0 / (2.0 * eigval[2] + 2.0 * lam[k])
        w0, w1, w2 = _p_inv(V, d0, d1, d2, 2.0 * m[k, 0], 2.0 * m[k, 1], 2.0 * m[k, 2])
        ig = 1.0 / (2.0 * m[k, 0] * w0 + 2.0 * m[k, 1] * w1 + 2.0 * m[k, 2] * w2)
        d[k, 0], d[k, 1], d[k, 2] = d0, d1, d2
        w[k, 0], w[k, 1], w[k, 2] = w0, w1, w2
        inv_gamma[k] = ig
        finite = finite and np.isfinite(d0) and np.isfinite(d1) and np.isfinite(d2) \
            and np.isfinite(ig)
    if not finite:
        return 1, np.zeros(9), np.zeros((K, 4))
    # S = A - sum_k C_k M_k C_k^T with M_k = P_k^-1 - w_k w_k^T / gamma_k (3x3, symmetric).
    # The h rows of every C_k are the same 2 T (A7), so only the T rows (6x3) vary with k:
    # S_TT -= sum_k C_Tk M_k C_Tk^T, S_Th -= (sum_k C_Tk M_k) 2 T^T, S_hh -= 2T (sum_k M_k) 2T^T.
    # x0_k = D_k^-1 g_k enters the reduced right-hand side.
    S_TT = np.zeros((6, 6))
    sum_CM = np.zeros((6, 3))
    sum_M = np.zeros((3, 3))
    sum_x0 = np.zeros(3)
    reduced_rhs = g_g.copy()
    C = np.empty((6, 3))
    CM = np.empty((6, 3))
    V00, V01, V02, V10, V11, V12, V20, V21, V22 = (V[0, 0], V[0, 1], V[0, 2], V[1, 0], V[1, 1],
                                                   V[1, 2], V[2, 0], V[2, 1], V[2, 2])
    for k in range(K):
        _coupling(T, m, r, k, C)
        # M_k in scalars (symmetric: six entries), so that the compiler keeps them in
        # registers instead of storing and reloading them around every use.
        d0, d1, d2, ig = d[k, 0], d[k, 1], d[k, 2], inv_gamma[k]
        w0, w1, w2 = w[k, 0], w[k, 1], w[k, 2]
        M00 = (V00 * d0 * V00 + V01 * d1 * V01 + V02 * d2 * V02) - w0 * w0 * ig
        M01 = (V00 * d0 * V10 + V01 * d1 * V11 + V02 * d2 * V12) - w0 * w1 * ig
        M02 = (V00 * d0 * V20 + V01 * d1 * V21 + V02 * d2 * V22) - w0 * w2 * ig
        M11 = (V10 * d0 * V10 + V11 * d1 * V11 + V12 * d2 * V12) - w1 * w1 * ig
        M12 = (V10 * d0 * V20 + V11 * d1 * V21 + V12 * d2 * V22) - w1 * w2 * ig
        M22 = (V20 * d0 * V20 + V21 * d1 * V21 + V22 * d2 * V22) - w2 * w2 * ig
        sum_M[0, 0] += M00
        sum_M[0, 1] += M01
        sum_M[0, 2] += M02
        sum_M[1, 1] += M11
        sum_M[1, 2] += M12
        sum_M[2, 2] += M22
        x00, x01, x02, _ = _bordered_solve(V, d, w, inv_gamma, k, g_l[k, 0], g_l[k, 1],
                                           g_l[k, 2], g_l[k, 3])
        sum_x0[0] += x00
        sum_x0[1] += x01
        sum_x0[2] += x02
        for e in range(6):
            c0, c1, c2 = C[e, 0], C[e, 1], C[e, 2]
            CM[e, 0] = c0 * M00 + c1 * M01 + c2 * M02
            CM[e, 1] = c0 * M01 + c1 * M11 + c2 * M12
            CM[e, 2] = c0 * M02 + c1 * M12 + c2 * M22
            reduced_rhs[e] -= c0 * x00 + c1 * x01 + c2 * x02
        for e in range(6):
            q0, q1, q2 = CM[e, 0], CM[e, 1], CM[e, 2]
            sum_CM[e, 0] += q0
            sum_CM[e, 1] += q1
            sum_CM[e, 2] += q2
            for f in range(e, 6):
                S_TT[e, f] += q0 * C[f, 0] + q1 * C[f, 1] + q2 * C[f, 2]
    for a in range(3):
        for b in range(a):
            sum_M[a, b] = sum_M[b, a]
    T2 = 2.0 * T
    S = A.copy()
    for e in range(6):
        for f in range(e, 6):
            S[e, f] -= S_TT[e, f]
            S[f, e] = S[e, f]
        for a in range(3):
            S[e, 6 + a] -= sum_CM[e, 0] * T2[a, 0] + sum_CM[e, 1] * T2[a, 1] \
                + sum_CM[e, 2] * T2[a, 2]
            S[6 + a, e] = S[e, 6 + a]
    hMh = T2 @ sum_M @ T2.T
    for a in range(3):
        reduced_rhs[6 + a] -= T2[a, 0] * sum_x0[0] + T2[a, 1] * sum_x0[1] + T2[a, 2] * sum_x0[2]
        for b in range(3):
            S[6 + a, 6 + b] -= hMh[a, b]
    if not np.all(np.isfinite(S)) or np.linalg.cond(S) > MAX_CONDITION:
        return 2, np.zeros(9), np.zeros((K, 4))
    dg = np.linalg.solve(S, reduced_rhs)
    dl = np.empty((K, 4))
    for k in range(K):
        _coupling(T, m, r, k, C)
        p0 = g_l[k, 0] - _coupled_step(C, T2, dg, 0)
        p1 = g_l[k, 1] - _coupled_step(C, T2, dg, 1)
        p2 = g_l[k, 2] - _coupled_step(C, T2, dg, 2)
        dl[k, 0], dl[k, 1], dl[k, 2], dl[k, 3] = _bordered_solve(V, d, w, inv_gamma, k, p0, p1,
                                                                 p2, g_l[k, 3])
    return 0, dg, dl


def newton_step(y: np.ndarray, s: State) -> tuple[np.ndarray, np.ndarray]:
    """The step ``[grad^2 J]^-1 grad J`` of eq. (54), by a Schur complement on the blocks.

    With ``H = [[A, B], [B^T, D]]``, D block diagonal and ``B_k = [C_k, 0]``, the global step
    solves ``(A - sum_k B_k D_k^-1 B_k^T) dg = g_g - sum_k B_k D_k^-1 g_k`` and the local steps
    are ``dl_k = D_k^-1 (g_k - B_k^T dg)``. Since the lambda column of ``B_k`` is zero,
    ``B_k D_k^-1 B_k^T = C_k (P_k^-1 - w_k w_k^T / gamma_k) C_k^T`` (see :func:`_newton` for
    ``D_k^-1``), summed over k in one compiled loop.

    Returns
    -------
    dg : ndarray, shape (9,)
        Step of ``[T (upper, vec order), h]``.
    dl : ndarray, shape (K, 4)
        Step of ``[m_k, lambda_k]``.

    Raises
    ------
    CalibrationFailed
        If a per-sample block or the reduced 9x9 system is singular.
    """
    status, dg, dl = _newton(*_arrays(y, s))
    if status == 1:
        raise CalibrationFailed("Gauss-Newton: a per-sample Hessian block [[2T^T T + "
                                "2 lambda_k I, 2 m_k], [2 m_k^T, 0]] is singular")
    if status == 2:
        raise CalibrationFailed("Gauss-Newton: the reduced Hessian (Schur complement) is "
                                "singular")
    return dg, dl


def apply_step(s: State, dg: np.ndarray, dl: np.ndarray) -> State:
    """``x - step`` (54) in the structured form."""
    T = s.T.copy()
    T[UPPER_ROWS, UPPER_COLS] -= dg[:6]
    return State(T, s.h - dg[6:], s.m - dl[:, :3], s.lam - dl[:, 3])


def initial_state(y: np.ndarray, T0: np.ndarray, h0: np.ndarray) -> State:
    """x(0) of eq. (57): ``m_k(0) = T0^-1 (y_k - h0)`` and ``lambda_k(0) = 0``."""
    T0 = np.array(T0, dtype=float)
    if T0.shape != (3, 3) or np.any(np.tril(T0, -1) != 0.0):
        raise ValueError("T0 must be an upper-triangular 3x3 matrix")
    h0 = np.array(h0, dtype=float).reshape(3)
    # A solve, not T0^-1 times the data: the printed variant's start is far off and its
    # iteration chaotic on some datasets, where the other rounding sent runs elsewhere.
    m0 = np.linalg.solve(T0, (y - h0).T).T
    return State(T0, h0, m0, np.zeros(y.shape[0]))


def refine(samples: np.ndarray, T0: np.ndarray, h0: np.ndarray, *, max_iter: int = 50,
           xtol: float = 1e-10, rtol: float = 1e-12) -> tuple[Calibration, np.ndarray]:
    """Newton iterations (54) on the Lagrangian (52) from a given ``(T_hat(0), h(0))``.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k``.
    T0 : ndarray, shape (3, 3)
        Upper-triangular starting ``T_hat``; ``m_k`` and ``lambda_k`` start as in (57).
    h0 : ndarray, shape (3,)
        Starting ``h``.
    max_iter : int
        Iteration cap.
    xtol : float
        Stop when the step of the nine calibration unknowns satisfies
        ``max|d(T, h)| <= xtol * max(1, max|(T, h)|)``. Newton converges quadratically, so
        this ends noise-free and noisy runs alike. 0 disables the rule.
    rtol : float
        Stop when the Lagrangian (52) changes by at most ``rtol`` times its previous value.
        The review's rule, "until J(x) becomes sufficiently small", cannot be used as it stands:
        ``J`` is zero at the initial estimate (57), whose ``m_k(0)`` fit the data exactly, and
        grows to the noise floor. 0 disables the rule.

    Returns
    -------
    Calibration
        ``T = T_hat`` (upper triangular) and ``h``; ``converged`` is False at the cap.
    history : ndarray, shape (n_iter + 1,)
        Wu and Shi's objective (4), ``sum_k ||y_k - T m_k - h||^2``, at x(0), x(1), ...
        (their Figure 3; at x(0) it is zero by construction).

    Raises
    ------
    CalibrationFailed
        Singular Hessian blocks, or a non-finite iterate (divergence).
    """
    y = samples
    s = initial_state(y, T0, h0)
    history = [objective(y, s)]
    previous = lagrangian(y, s, history[0])
    for it in range(1, max_iter + 1):
        dg, dl = newton_step(y, s)
        s = apply_step(s, dg, dl)
        if not (np.all(np.isfinite(s.T)) and np.all(np.isfinite(s.h))
                and np.all(np.isfinite(s.m)) and np.all(np.isfinite(s.lam))):
            raise CalibrationFailed(f"Gauss-Newton diverged (non-finite iterate at "
                                    f"iteration {it})")
        history.append(objective(y, s))
        current = lagrangian(y, s, history[-1])
        size = max(1.0, float(np.max(np.abs(np.concatenate([s.T.ravel(), s.h])))))
        step_small = float(np.max(np.abs(dg))) <= xtol * size
        cost_flat = abs(current - previous) <= rtol * abs(previous)
        if step_small or cost_flat:
            rule = "step" if step_small else "relative change of J (52)"
            return (Calibration(s.T, s.h, it, True,
                                f"{rule} rule met after {it} iterations, objective (4) "
                                f"{history[-1]:.3g}, max | ||m_k|| - 1 | "
                                f"{np.max(np.abs(row_norms(s.m) - 1.0)):.2g}"),
                    np.array(history))
        previous = current
    return (Calibration(s.T, s.h, max_iter, False,
                        f"iteration cap {max_iter} reached, objective (4) {history[-1]:.3g}"),
            np.array(history))


@register("wu_shi", label="Wu-Shi", min_samples=10, paper_key="Wu_Shi")
def fit(samples: np.ndarray, *, max_iter: int = 50, xtol: float = 1e-10, rtol: float = 1e-12,
        null_vector: str = "svd", t0_form: str = "inverse") -> Calibration:
    """Calibrate with Wu and Shi's optimal ML estimator (Algorithm 6).

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k`` near unit field magnitude.
    max_iter, xtol, rtol : see :func:`refine`.
    null_vector : {"svd", "eigh"}
        How step 2 finds the eigenvector of ``Y^T Y`` for its smallest eigenvalue: ``"svd"``
        (default, the smallest right singular vector of ``Y``, better conditioned) or
        ``"eigh"`` (the paper's literal eigen-decomposition of ``Y^T Y``).
    t0_form : {"inverse", "chol"}
        ``"inverse"`` (default): Wu and Shi's start ``T_hat(0) = chol(A)^-1``. ``"chol"``: the
        review's eq. (57) as printed, ``T_hat(0) = chol(A)`` (that is ``R``, not ``R^-1``); with
        it Newton diverges or stalls in about 12 % of the nominal runs, close to the review's
        RB of 87.2 % (Table 2), while the default succeeds in all of them.

    Returns
    -------
    Calibration
        ``T = T_hat`` upper triangular and ``h``.

    Raises
    ------
    CalibrationFailed
        ``A`` not positive definite in the initial estimate (57), a singular Hessian, or
        divergence.
    """
    T0, h0 = initial_estimate(samples, null_vector=null_vector, t0_form=t0_form)
    return refine(samples, T0, h0, max_iter=max_iter, xtol=xtol, rtol=rtol)[0]


# The review's printed eq. (57), T_hat(0) = chol(A), starts Newton from R instead of R^-1 (Wu
# and Shi's T(0) = (R(0))^-1): registered as its own method so every sweep shows its effect.
# It reproduces the review's Wu-Shi robustness (RB 87.2 % at the nominal point, Table 2).
register("wu_shi_printed", label="Wu-Shi (review's printed (57))", min_samples=10,
         family="variant")(partial(fit, t0_form="chol"))
