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
def _residuals_into(y: np.ndarray, T: np.ndarray, h: np.ndarray, m: np.ndarray, r: np.ndarray
                    ) -> None:
    """Write ``r_k = u_k - T m_k`` with ``u_k = y_k - h`` (Appendix A.2) into ``r (K, 3)``."""
    for k in range(y.shape[0]):
        for a in range(3):
            r[k, a] = y[k, a] - h[a] - (m[k, 0] * T[a, 0] + m[k, 1] * T[a, 1]
                                        + m[k, 2] * T[a, 2])


@njit
def _residuals(y: np.ndarray, T: np.ndarray, h: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``r_k = u_k - T m_k`` with ``u_k = y_k - h`` (Appendix A.2), shape ``(K, 3)``."""
    r = np.empty((y.shape[0], 3))
    _residuals_into(y, T, h, m, r)
    return r


def _arrays(y: np.ndarray, s: State) -> tuple[np.ndarray, ...]:
    """``y, T, h, m, lam`` as contiguous float arrays, as the compiled functions take them."""
    return tuple(np.ascontiguousarray(a, dtype=np.float64) for a in (y, s.T, s.h, s.m, s.lam))


def residuals(y: np.ndarray, s: State) -> np.ndarray:
    """``r_k = u_k - T m_k`` with ``u_k = y_k - h`` (Appendix A.2), shape ``(K, 3)``."""
    return _residuals(*_arrays(y, s)[:4])


def _sum_of_squares(r: np.ndarray) -> float:
    """``sum_k ||r_k||^2``: the objective (4) from the residuals.

    NumPy's einsum, not a compiled loop: its summation order is not a plain sequential one, and
    the objective feeds refine's relative-change rule, so another order could end a run at
    another iteration."""
    return float(np.einsum("ij,ij->", r, r))


def _constraint_term(m: np.ndarray, lam: np.ndarray) -> float:
    """``sum_k lambda_k (||m_k||^2 - 1)``, the constraint term of (52) (NumPy, as the sums of
    :func:`_sum_of_squares`)."""
    return float(lam @ (np.einsum("ij,ij->i", m, m) - 1.0))


def objective(y: np.ndarray, s: State) -> float:
    """Wu and Shi's ML objective (4) = review (51): ``sum_k ||y_k - T m_k - h||^2``."""
    return _sum_of_squares(residuals(y, s))


def lagrangian(y: np.ndarray, s: State, objective_value: float | None = None) -> float:
    """The Lagrange function J(x) of eq. (52).

    ``objective_value``, if given, is ``objective(y, s)`` already computed (refine needs both
    and the objective is most of the cost).
    """
    obj = objective(y, s) if objective_value is None else objective_value
    return obj + _constraint_term(s.m, s.lam)


@njit
def _gradient_from(r: np.ndarray, T: np.ndarray, m: np.ndarray, lam: np.ndarray,
                   g_l: np.ndarray) -> np.ndarray:
    """:func:`gradient` from the residuals ``r`` of :func:`_residuals`: returns the global
    entries and writes the local ones, transposed, into ``g_l (4, K)``."""
    K = r.shape[0]
    g_g = np.zeros(9)
    for k in range(K):
        for e in range(6):                                         # J_T (A4)
            g_g[e] += -2.0 * r[k, _UR[e]] * m[k, _UC[e]]
        for a in range(3):                                         # J_h
            g_g[6 + a] += -2.0 * r[k, a]
        for j in range(3):                                         # -2 T^T r_k + 2 lam_k m_k
            g_l[j, k] = -2.0 * (r[k, 0] * T[0, j] + r[k, 1] * T[1, j] + r[k, 2] * T[2, j]) \
                + 2.0 * lam[k] * m[k, j]
        g_l[3, k] = m[k, 0] ** 2 + m[k, 1] ** 2 + m[k, 2] ** 2 - 1.0
    return g_g


@njit
def _gradient(y: np.ndarray, T: np.ndarray, h: np.ndarray, m: np.ndarray, lam: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    g_l = np.empty((4, y.shape[0]))
    g_g = _gradient_from(_residuals(y, T, h, m), T, m, lam, g_l)
    return g_g, g_l.T.copy()


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
    a ``(K, 9, 3)`` array's memory traffic cost more than its arithmetic. (Its last pass writes
    the same entries out as scalars, ``- 0.0`` dropped where ``b != c``: ``x - 0.0 == x``.)
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
def _p_inv(V: tuple, d0: float, d1: float, d2: float, p0: float, p1: float, p2: float
           ) -> tuple[float, float, float]:
    """``P_k^-1 p_k = V diag(d_k) V^T p_k`` for one sample (see :func:`_newton`); ``V`` is the
    tuple ``(V00, V01, ..., V22)`` of the eigenvectors' entries, row by row."""
    V00, V01, V02, V10, V11, V12, V20, V21, V22 = V
    t0 = (p0 * V00 + p1 * V10 + p2 * V20) * d0
    t1 = (p0 * V01 + p1 * V11 + p2 * V21) * d1
    t2 = (p0 * V02 + p1 * V12 + p2 * V22) * d2
    return (t0 * V00 + t1 * V01 + t2 * V02,
            t0 * V10 + t1 * V11 + t2 * V12,
            t0 * V20 + t1 * V21 + t2 * V22)


@njit
def _bordered_solve(V: tuple, d0: float, d1: float, d2: float, ig: float, w0: float, w1: float,
                    w2: float, p0: float, p1: float, p2: float, q: float
                    ) -> tuple[float, float, float, float]:
    """``[x; mu] = D_k^-1 [p_k; q_k]`` for one sample from its ``d_k``, ``1 / gamma_k`` and
    ``w_k`` (see :func:`_newton`)."""
    x0, x1, x2 = _p_inv(V, d0, d1, d2, p0, p1, p2)
    mu = (w0 * p0 + w1 * p1 + w2 * p2 - q) * ig
    return x0 - w0 * mu, x1 - w1 * mu, x2 - w2 * mu, mu


#: Rows of :func:`_newton`'s work array (times K samples).
WORK_ROWS = 21


@njit
def _newton(r: np.ndarray, T: np.ndarray, m: np.ndarray, lam: np.ndarray, work: np.ndarray
            ) -> tuple[int, np.ndarray, np.ndarray]:
    """The step of :func:`newton_step` from the residuals ``r`` of :func:`_residuals`: status 0,
    or 1 (singular ``D_k``), 2 (singular S); ``dg``; ``dl`` transposed, shape ``(4, K)``, a view
    of ``work``.

    ``work (WORK_ROWS, K)`` holds the per-sample arrays; refine passes the same one at every
    iteration, so that an iteration takes no new memory from the system (fresh pages cost more
    than the arithmetic that fills them).

    ``D_k^-1`` for all k at once, ``D_k = [[P_k, a_k], [a_k^T, 0]]``, ``P_k = 2 T^T T +
    2 lam_k I``, ``a_k = 2 m_k``: all ``P_k`` share the eigenvectors V of ``T^T T``, so
    ``P_k^-1 = V diag(d_k) V^T`` with ``d_k = 1 / (2 eig(T^T T) + 2 lam_k)``, one 3x3
    eigen-decomposition per iteration instead of K 4x4 solves. With ``w_k = P_k^-1 a_k`` and
    ``gamma_k = a_k^T w_k``, the solution of ``D_k [x; mu] = [p; q]`` is
    ``mu = (w_k^T p - q) / gamma_k``, ``x = P_k^-1 p - w_k mu``.

    The per-sample passes that sum nothing (``d_k, w_k, gamma_k`` first, the local steps last)
    run on one-row-per-quantity arrays with the 3x3 entries held in scalars, so that the
    compiler vectorises them over the samples: the same operations on each sample, so the same
    results, several samples per instruction. The pass that sums over the samples (the Schur
    complement) stays sequential in k, in its order.
    """
    K = r.shape[0]
    g_l = work[0:4]                         # rows of the local gradient (A6)
    g_g = _gradient_from(r, T, m, lam, g_l)
    A = _global_block(T, m)
    eigval, V = np.linalg.eigh(T.T @ T)
    Vt = (V[0, 0], V[0, 1], V[0, 2], V[1, 0], V[1, 1], V[1, 2], V[2, 0], V[2, 1], V[2, 2])
    e0, e1, e2 = 2.0 * eigval[0], 2.0 * eigval[1], 2.0 * eigval[2]
    # m and r one row per component: the vectorised passes load them contiguously.
    mt = work[4:7]
    rt = work[7:10]
    for k in range(K):
        for a in range(3):
            mt[a, k] = m[k, a]
            rt[a, k] = r[k, a]
    m0, m1, m2, r0, r1, r2 = mt[0], mt[1], mt[2], rt[0], rt[1], rt[2]
    dw = work[10:17]                        # rows d_k (3), 1 / gamma_k, w_k (3)
    d0, d1, d2, ig, w0, w1, w2 = dw[0], dw[1], dw[2], dw[3], dw[4], dw[5], dw[6]
    finite = True
    for k in range(K):
        l2 = 2.0 * lam[k]
        d0[k] = 1.0 / (e0 + l2)
        d1[k] = 1.0 / (e1 + l2)
        d2[k] = 1.0 / (e2 + l2)
        a0, a1, a2 = 2.0 * m0[k], 2.0 * m1[k], 2.0 * m2[k]
        w0[k], w1[k], w2[k] = _p_inv(Vt, d0[k], d1[k], d2[k], a0, a1, a2)
        ig[k] = 1.0 / (a0 * w0[k] + a1 * w1[k] + a2 * w2[k])
        # x - x is 0 for finite x and NaN otherwise: a test without a branch, which vectorises.
        finite &= (d0[k] - d0[k]) + (d1[k] - d1[k]) + (d2[k] - d2[k]) + (ig[k] - ig[k]) == 0.0
    if not finite:
        return 1, np.zeros(9), work[17:21]
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
    V00, V01, V02, V10, V11, V12, V20, V21, V22 = Vt
    for k in range(K):
        _coupling(T, m, r, k, C)
        # M_k in scalars (symmetric: six entries), so that the compiler keeps them in
        # registers instead of storing and reloading them around every use.
        dk0, dk1, dk2, igk = d0[k], d1[k], d2[k], ig[k]
        wk0, wk1, wk2 = w0[k], w1[k], w2[k]
        M00 = (V00 * dk0 * V00 + V01 * dk1 * V01 + V02 * dk2 * V02) - wk0 * wk0 * igk
        M01 = (V00 * dk0 * V10 + V01 * dk1 * V11 + V02 * dk2 * V12) - wk0 * wk1 * igk
        M02 = (V00 * dk0 * V20 + V01 * dk1 * V21 + V02 * dk2 * V22) - wk0 * wk2 * igk
        M11 = (V10 * dk0 * V10 + V11 * dk1 * V11 + V12 * dk2 * V12) - wk1 * wk1 * igk
        M12 = (V10 * dk0 * V20 + V11 * dk1 * V21 + V12 * dk2 * V22) - wk1 * wk2 * igk
        M22 = (V20 * dk0 * V20 + V21 * dk1 * V21 + V22 * dk2 * V22) - wk2 * wk2 * igk
        sum_M[0, 0] += M00
        sum_M[0, 1] += M01
        sum_M[0, 2] += M02
        sum_M[1, 1] += M11
        sum_M[1, 2] += M12
        sum_M[2, 2] += M22
        x00, x01, x02, _ = _bordered_solve(Vt, dk0, dk1, dk2, igk, wk0, wk1, wk2, g_l[0, k],
                                           g_l[1, k], g_l[2, k], g_l[3, k])
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
        return 2, np.zeros(9), work[17:21]
    dg = np.linalg.solve(S, reduced_rhs)
    # dl_k = D_k^-1 (g_k - B_k^T dg). The m_k rows of B_k^T dg are C_k^T dg_T + (2 T)^T dg_h,
    # with C_k's entries (_coupling) written out, (a, b) = UPPER[e], C_k[e, c] =
    # 2 m_b T_ac - [b == c] 2 r_a, summed in the order e = 0..5, then the h rows.
    T00, T01, T02, T10, T11, T12, T20, T21, T22 = (T[0, 0], T[0, 1], T[0, 2], T[1, 0], T[1, 1],
                                                   T[1, 2], T[2, 0], T[2, 1], T[2, 2])
    H00, H01, H02, H10, H11, H12, H20, H21, H22 = (T2[0, 0], T2[0, 1], T2[0, 2], T2[1, 0],
                                                   T2[1, 1], T2[1, 2], T2[2, 0], T2[2, 1],
                                                   T2[2, 2])
    g0, g1, g2, g3, g4, g5, g6, g7, g8 = (dg[0], dg[1], dg[2], dg[3], dg[4], dg[5], dg[6],
                                          dg[7], dg[8])
    q0, q1, q2, q3 = g_l[0], g_l[1], g_l[2], g_l[3]
    dl = work[17:21]
    dl0, dl1, dl2, dl3 = dl[0], dl[1], dl[2], dl[3]
    for k in range(K):
        b0, b1, b2 = 2.0 * m0[k], 2.0 * m1[k], 2.0 * m2[k]
        s0, s1, s2 = 2.0 * r0[k], 2.0 * r1[k], 2.0 * r2[k]
        p0 = q0[k] - ((b0 * T00 - s0) * g0 + b1 * T00 * g1 + b1 * T10 * g2 + b2 * T00 * g3
                      + b2 * T10 * g4 + b2 * T20 * g5 + H00 * g6 + H10 * g7 + H20 * g8)
        p1 = q1[k] - (b0 * T01 * g0 + (b1 * T01 - s0) * g1 + (b1 * T11 - s1) * g2
                      + b2 * T01 * g3 + b2 * T11 * g4 + b2 * T21 * g5 + H01 * g6 + H11 * g7
                      + H21 * g8)
        p2 = q2[k] - (b0 * T02 * g0 + b1 * T02 * g1 + b1 * T12 * g2 + (b2 * T02 - s0) * g3
                      + (b2 * T12 - s1) * g4 + (b2 * T22 - s2) * g5 + H02 * g6 + H12 * g7
                      + H22 * g8)
        dl0[k], dl1[k], dl2[k], dl3[k] = _bordered_solve(Vt, d0[k], d1[k], d2[k], ig[k], w0[k],
                                                         w1[k], w2[k], p0, p1, p2, q3[k])
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
    y, T, h, m, lam = _arrays(y, s)
    work = np.empty((WORK_ROWS, y.shape[0]))
    dg, dl = _checked_step(_residuals(y, T, h, m), T, m, lam, work)
    return dg, np.ascontiguousarray(dl.T)


def _checked_step(r: np.ndarray, T: np.ndarray, m: np.ndarray, lam: np.ndarray,
                  work: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_newton`, raising :class:`CalibrationFailed` for its failure statuses; ``dl`` is
    returned transposed, shape ``(4, K)``."""
    status, dg, dl = _newton(r, T, m, lam, work)
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


@njit
def _advance(y: np.ndarray, T: np.ndarray, h: np.ndarray, m: np.ndarray, lam: np.ndarray,
             dg: np.ndarray, dl: np.ndarray, r: np.ndarray) -> tuple[bool, float, float]:
    """:func:`apply_step` in place on refine's arrays (``dl`` transposed, as :func:`_newton`
    returns it), and the residuals of the new x into r.

    One compiled pass instead of a NumPy call per array (each cost more in overhead and new
    arrays than in arithmetic at K = 10 000); every entry is the same one subtraction.

    Returns
    -------
    finite : bool
        Whether the new x is finite.
    size : float
        ``max |(T, h)|`` of the new x (the scale of refine's step rule).
    step : float
        ``max |dg|``.
    """
    for e in range(6):
        T[_UR[e], _UC[e]] -= dg[e]
    for a in range(3):
        h[a] -= dg[6 + a]
    finite = True
    size = 0.0
    step = 0.0
    for a in range(3):
        for b in range(3):
            finite = finite and np.isfinite(T[a, b])
            size = max(size, abs(T[a, b]))
        finite = finite and np.isfinite(h[a])
        size = max(size, abs(h[a]))
    for e in range(9):
        step = max(step, abs(dg[e]))
    for k in range(m.shape[0]):
        m[k, 0] -= dl[0, k]
        m[k, 1] -= dl[1, k]
        m[k, 2] -= dl[2, k]
        lam[k] -= dl[3, k]
        finite = finite and np.isfinite(m[k, 0]) and np.isfinite(m[k, 1]) \
            and np.isfinite(m[k, 2]) and np.isfinite(lam[k])
    _residuals_into(y, T, h, m, r)
    return finite, size, step


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
    s = initial_state(samples, T0, h0)
    # x lives in contiguous arrays of refine's own (initial_state copies T0 and h0), updated
    # in place by _advance: the iterates of apply_step without new arrays. Each x's residuals
    # serve both its objective and the next Newton step.
    y, T, h, m, lam = _arrays(samples, s)
    r = _residuals(y, T, h, m)
    work = np.empty((WORK_ROWS, y.shape[0]))
    history = [_sum_of_squares(r)]
    previous = history[0] + _constraint_term(m, lam)           # the Lagrangian (52)
    for it in range(1, max_iter + 1):
        dg, dl = _checked_step(r, T, m, lam, work)
        finite, size, step = _advance(y, T, h, m, lam, dg, dl, r)
        if not finite:
            raise CalibrationFailed(f"Gauss-Newton diverged (non-finite iterate at "
                                    f"iteration {it})")
        history.append(_sum_of_squares(r))
        current = history[-1] + _constraint_term(m, lam)
        step_small = step <= xtol * max(1.0, size)
        cost_flat = abs(current - previous) <= rtol * abs(previous)
        if step_small or cost_flat:
            rule = "step" if step_small else "relative change of J (52)"
            return (Calibration(T, h, it, True,
                                f"{rule} rule met after {it} iterations, objective (4) "
                                f"{history[-1]:.3g}, max | ||m_k|| - 1 | "
                                f"{np.max(np.abs(row_norms(m) - 1.0)):.2g}"),
                    np.array(history))
        previous = current
    return (Calibration(T, h, max_iter, False,
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
