"""Joint magnetometer-IMU calibration with the orientation trajectory as unknowns (Huang,
Hendeby and Skog, "Joint Magnetometer-IMU Calibration via Maximum A Posteriori Estimation",
arXiv:2505.16662, 2025). Kok and Schon, "Magnetometer calibration using inertial sensors",
IEEE Sensors J. 16(14), 2016 (arXiv:1601.05257), estimate the same magnetometer parameters
and misalignment by maximum likelihood with the orientation filtered rather than estimated
(the companion code's ML baseline, a likelihood of filter innovations).

Sources. Neither paper's numbered equations could be read (only the opening pages and
abstracts are in the reference corpus), so no equation numbers are cited here. What is
confirmed: Huang et al.'s abstract (a MAP estimate with the calibration parameters and the
orientation trajectory as unknowns, analytic derivatives; "IMU preintegration" among the index
terms of v2), Kok and Schon's abstract (maximum likelihood, offline, magnetometer errors,
disturbances and the misalignment to the inertial axes), and the structure of the authors'
companion code (Huang-Chuan/Mag-IMU-JointCalibration, JointMAP/), which the model below
follows: magnetometer ``y = D R^T m + o``, accelerometer with a bias, a gyro residual on the
preintegrated rotation, the field by its dip angle.

Unknowns: the magnetometer's ``G`` (3x3, in the IMU's axes, so it holds the mounting
rotation) and ``h``, the field's inclination ``theta``, the gyro bias ``b``, the
accelerometer bias ``b_acc`` and the orientation ``Q_k`` (IMU to world) at every sample. With
the world's z axis up, gravity's specific force ``g_w = (0, 0, g)`` and the field ``m_w = (0,
cos theta, sin theta)`` (the world's y axis along its horizontal part, which fixes the heading
gauge), the residuals are

    magnetometer   y_k - G Q_k^T m_w - h                                  / sigma_mag
    accelerometer  a_k - Q_k^T g_w - b_acc                                / sigma_acc
    gyroscope      Log(Exp(-(w_k - b) dt_k) Q_k^T Q_{k+1})                / (sigma_gyro dt_k)

(``w_k`` the mean of the two rate samples of the interval). Linear accelerations enter as
accelerometer noise. The minimum is found by Levenberg-Marquardt over the 19 parameters and
the 3K orientation increments (``Q_k <- Q_k Exp(d_k)``), whose normal equations are sparse
(block tridiagonal plus a dense border) and are solved as such (:class:`BorderedSystem`).

Named differences from the paper's estimator (as its companion code shows it):

* Priors: none (flat), so the estimate is the maximum-likelihood one. The companion code's
  residual has no prior rows either.
* Preintegration: one interval per sample. The paper preintegrates the gyro over several
  samples and keeps an orientation (and an accelerometer and magnetometer sample) only at
  every L-th sample; here every sample keeps its orientation (L = 1), so no sample is dropped.
* Gyro bias: inside the interval's rotation, with its exact Jacobian; the paper corrects the
  preintegrated rotation to first order in the bias change about a nominal bias.
* Solver: Levenberg-Marquardt; the paper's code takes Gauss-Newton steps (QR). Same minimum.
* Gravity's magnitude: known in the paper; here the median specific-force norm unless
  ``gravity`` is given (a bias shifts that median slightly).
* Start: MAG.I.C.AL. (review Algorithm 7, eqs. 58-65) for ``G`` and ``h`` with the alignment
  the identity, ``theta`` from the mean dot product of the field and gravity directions, and
  every orientation from the accelerometer and that field direction (TRIAD). The paper's code
  starts from a magnetometer ellipsoid fit, a misalignment from the gyro and magnetometer
  (Wu et al.'s method), a given dip angle, and orientations integrated from the gyro.
* The IMU's other errors (scale factors, the gyro's misalignment) are not estimated.

The result's ``T = G``: ``T^-1 (y - h)`` is the field in the IMU's axes, the alignment is the
rotation ``G^-1 (G G^T)^(1/2)`` and the gyro bias is returned; the accelerometer bias is in
the message.
"""

from __future__ import annotations

import numpy as np

from magbench.core.crb import alignment_rotation
from magbench.core.model import Calibration, CalibrationFailed
from magbench.core.rotations import rotation_exp, skew
from magbench.methods.algorithms._alignment_common import (
    check_acceleration,
    symmetric_directions,
    unit_rows,
)
from magbench.methods.algorithms._gyro_common import check_gyro_inputs
from magbench.methods.algorithms.magical import iterate
from magbench.methods.registry import register

N_PARAMS = 19          # vec G (9, row-major), h (3), theta (1), b (3), b_acc (3)
N_FIXED_ACC = 16       # the same without the accelerometer bias (``accel_bias=False``)


def rotation_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors of ``(..., 3, 3)`` rotations (angles below pi)."""
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    v = 0.5 * np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                        R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    small = theta < 1e-6
    factor = np.where(small, 1.0 + theta**2 / 6.0, theta / np.sin(np.where(small, 1.0, theta)))
    return v * factor[..., None]


def right_jacobian_inverse(x: np.ndarray) -> np.ndarray:
    """``Jr^-1(x)`` of SO(3) for ``(N, 3)`` rotation vectors: ``Log(Exp(x) Exp(d)) = x +
    Jr^-1(x) d`` to first order."""
    theta = np.linalg.norm(x, axis=-1)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    c = np.where(small, 1.0 / 12.0, 1.0 / t**2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    K = skew(x)
    return np.eye(3) + 0.5 * K + c[:, None, None] * (K @ K)


def right_jacobian(x: np.ndarray) -> np.ndarray:
    """``Jr(x)``: ``Exp(x + d) = Exp(x) Exp(Jr(x) d)`` to first order."""
    theta = np.linalg.norm(x, axis=-1)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5, (1.0 - np.cos(t)) / t**2)
    b = np.where(small, 1.0 / 6.0, (t - np.sin(t)) / t**3)
    K = skew(x)
    return np.eye(3) - a[:, None, None] * K + b[:, None, None] * (K @ K)


def triad(up: np.ndarray, field: np.ndarray) -> np.ndarray:
    """Orientations (IMU to world; world x east, y north, z up) from unit up and field
    directions in the IMU's axes."""
    east = unit_rows(np.cross(field, up))
    north = np.cross(up, east)
    return np.stack([east, north, up], axis=1)


def field_world(theta: float) -> tuple[np.ndarray, np.ndarray]:
    """``m_w(theta)`` and its derivative."""
    return (np.array([0.0, np.cos(theta), np.sin(theta)]),
            np.array([0.0, -np.sin(theta), np.cos(theta)]))


def residuals(Q, p, y, a, w_mid, dt, g_w, weights):
    """Weighted residual vector (mag, accel, gyro blocks) and what the Jacobian reuses.

    ``p`` holds 19 parameters, or 16 when the accelerometer bias is held at zero."""
    G, h, theta, b = p[:9].reshape(3, 3), p[9:12], p[12], p[13:16]
    b_acc = p[16:19] if p.size > N_FIXED_ACC else np.zeros(3)
    m_w, _ = field_world(theta)
    v = np.einsum("kji,j->ki", Q, m_w)
    u = np.einsum("kji,j->ki", Q, g_w)
    phi = (w_mid - b) * dt[:, None]
    C = np.einsum("kji,kjl->kil", Q[:-1], Q[1:])                  # Q_k^T Q_{k+1}
    E = np.einsum("kij,kjl->kil", rotation_exp(-phi), C)          # Exp(-phi) C
    r_g = rotation_log(E)
    wm, wa, wg = weights
    r = np.concatenate([((y - v @ G.T - h) * wm).ravel(), ((a - u - b_acc) * wa).ravel(),
                        (r_g * (wg / dt)[:, None]).ravel()])
    return r, (v, u, phi, C, r_g)


def jacobian(Q, p, parts, dt, weights) -> object:
    """Sparse Jacobian of :func:`residuals` in ``(d_0, ..., d_{K-1}, p)``."""
    from scipy import sparse  # imported when fitting: registering stays light

    K = Q.shape[0]
    G, theta = p[:9].reshape(3, 3), p[12]
    v, u, phi, C, r_g = parts
    wm, wa, wg = weights
    _, dm_w = field_world(theta)
    n = 3 * K
    rows, cols, vals = [], [], []

    def block(r0: np.ndarray, c0: np.ndarray, B: np.ndarray) -> None:
        # Dense (N, R, S) blocks at row offsets r0 and column offsets c0.
        R_, S_ = B.shape[1:]
        rows.append((r0[:, None, None] + np.arange(R_)[None, :, None] + 0 * B).ravel())
        cols.append((c0[:, None, None] + np.arange(S_)[None, None, :] + 0 * B).ravel())
        vals.append(B.ravel())

    k = np.arange(K)
    block(3 * k, 3 * k, -wm * (G @ skew(v)))                                  # mag / d_k
    dG = -wm * np.einsum("ij,kl->kijl", np.eye(3), v).reshape(K, 3, 9)
    block(3 * k, np.full(K, n), dG)                                           # mag / vec G
    block(3 * k, np.full(K, n + 9), np.broadcast_to(-wm * np.eye(3), (K, 3, 3)))
    dth = -wm * (np.einsum("kji,j->ki", Q, dm_w) @ G.T)
    block(3 * k, np.full(K, n + 12), dth[:, :, None])                         # mag / theta
    block(n + 3 * k, 3 * k, -wa * skew(u))                                    # acc / d_k
    if p.size > N_FIXED_ACC:
        block(n + 3 * k, np.full(K, n + 16), np.broadcast_to(-wa * np.eye(3), (K, 3, 3)))
    s = (wg / dt)[:, None, None]
    Jinv = right_jacobian_inverse(r_g)
    j = np.arange(K - 1)
    g0 = 2 * n
    block(g0 + 3 * j, 3 * (j + 1), s * Jinv)                                  # gyro / d_k+1
    block(g0 + 3 * j, 3 * j, -s * (Jinv @ np.swapaxes(C, 1, 2)))             # gyro / d_k
    Jb = Jinv @ np.swapaxes(C, 1, 2) @ right_jacobian(-phi) * dt[:, None, None]
    block(g0 + 3 * j, np.full(K - 1, n + 13), s * Jb)                         # gyro / b
    shape = (2 * n + 3 * (K - 1), n + p.size)
    return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                     np.concatenate(cols))), shape=shape)


def initial_state(y, a, max_iter, tol, rtol):
    """TRIAD orientations and MAG.I.C.AL.'s ``G``, ``h`` (no mounting rotation) to start."""
    T, h, *_ = iterate(np.ascontiguousarray(y), int(max_iter), float(tol), float(rtol), np.inf)
    T_s, m = symmetric_directions(y, T, h)
    up = unit_rows(a)
    if np.linalg.matrix_rank(np.cross(m, up), tol=1e-9) == 0:
        raise CalibrationFailed("MAP: the field is parallel to gravity; no heading")
    c = float(np.clip(np.mean(np.einsum("ki,ki->k", m, up)), -0.999, 0.999))
    p = np.concatenate([T_s.ravel(), h, [np.arcsin(c)], np.zeros(3)])
    return triad(up, m), p


@register("mag_imu_map", label="Mag-IMU MAP", min_samples=10, family="extra",
          needs_gyro=True, needs_accel=True)
def fit(samples: np.ndarray, *, angular_rate: np.ndarray, time: np.ndarray,
        acceleration: np.ndarray, sigma_mag: float = 0.01, sigma_acc: float = 0.05,
        sigma_gyro: float = 0.01, accel_bias: bool = True, gravity: float | None = None,
        max_iter: int = 50, xtol: float = 1e-10) -> Calibration:
    """Calibrate the magnetometer, its rotation to the IMU and the IMU's biases jointly.

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Magnetometer samples.
    angular_rate, time : ndarray
        Gyro samples (rad/s, IMU axes) and times (s).
    acceleration : ndarray, shape (K, 3)
        Accelerometer samples (specific force, IMU axes, any unit).
    sigma_mag, sigma_acc, sigma_gyro : float
        Noise of the magnetometer (in field strengths), accelerometer (in g, linear
        accelerations included) and gyro (rad/s): the residuals' weights.
    accel_bias : bool
        True (the paper's parameter set): the accelerometer's bias is an unknown, ``a_k -
        Q_k^T g_w - b_acc``; False holds it at zero (the accelerometer taken as calibrated).
    gravity : float or None
        Gravity's magnitude in the accelerometer's unit (known in the paper); None takes the
        median specific-force norm, which a bias shifts slightly.
    max_iter : int
        Levenberg-Marquardt iteration cap.
    xtol : float
        Stop when the largest parameter step is below this.

    Returns
    -------
    Calibration
        ``T = G`` (the field in IMU axes is ``T^-1 (y - h)``), ``h``, the alignment and the
        gyro bias; ``converged`` False at the iteration cap.
    """
    w, t = check_gyro_inputs(samples, angular_rate, time)
    a = check_acceleration(samples, acceleration)
    if gravity is None:
        g = float(np.median(np.sqrt(np.einsum("ij,ij->i", a, a))))
    elif gravity > 0:
        g = float(gravity)
    else:
        raise ValueError(f"gravity must be > 0 or None, got {gravity}")
    a = a / g
    Q, p = initial_state(samples, a, 2000, 1e-24, 1e-12)
    if accel_bias:
        p = np.concatenate([p, np.zeros(3)])
    # In units of the field strength, so that sigma_mag means the same in any unit.
    field = float(np.cbrt(abs(np.linalg.det(p[:9].reshape(3, 3)))))
    p[:12] /= field
    dt, w_mid = np.diff(t), 0.5 * (w[1:] + w[:-1])
    weights = (1.0 / sigma_mag, 1.0 / sigma_acc, 1.0 / sigma_gyro)
    g_w = np.array([0.0, 0.0, 1.0])
    Q, p, n_iter, converged = _solve(Q, p, samples / field, a, w_mid, dt, g_w, weights,
                                     max_iter, xtol)
    G, h, b = field * p[:9].reshape(3, 3), field * p[9:12], p[13:16]
    if not np.all(np.isfinite(G)) or abs(np.linalg.det(G)) < 1e-12:
        raise CalibrationFailed("MAP: the estimate of G is singular")
    if np.linalg.det(G) < 0:
        raise CalibrationFailed("MAP: the estimate of G is a mirror image (det G < 0): the "
                                "magnetometer's axes are left-handed against the IMU's (a "
                                "swapped or negated axis), or the fit went astray")
    incl = np.degrees(-p[12])
    dip = data_dip_deg(G, h, samples, a)
    if abs(incl - dip) > MAX_DIP_DISAGREEMENT_DEG:
        raise CalibrationFailed(f"MAP: the fitted inclination {incl:.1f} deg is "
                                f"{abs(incl - dip):.0f} deg from the data's own dip angle "
                                f"under the fitted G ({dip:.1f} deg): a wrong local minimum "
                                "(fast linear accelerations?)")
    message = (f"Levenberg-Marquardt {'converged' if converged else 'stopped at the cap'} after "
               f"{n_iter} iterations; inclination {incl:.2f} deg")
    if accel_bias:
        message += f"; accelerometer bias {np.array2string(g * p[16:19], precision=4)}"
    return Calibration(G, h, n_iter, converged, message, b, alignment_rotation(G))


#: Largest gap (deg) between the fitted inclination and the median angle between the specific
#: force and the field the fitted ``G`` gives: linear accelerations bias the latter on
#: hand-held motion, a fit in the wrong basin lies well beyond (evidence: docs/decisions.md).
MAX_DIP_DISAGREEMENT_DEG = 30.0


def data_dip_deg(G: np.ndarray, h: np.ndarray, y: np.ndarray, a: np.ndarray) -> float:
    """The field's dip below the horizontal (deg) that the samples show under ``G`` and ``h``:
    the median over samples of the angle between the field ``G^-1 (y - h)`` and the specific
    force ``a`` (up at rest), as 90 deg minus it."""
    m = unit_rows(np.linalg.solve(G, (y - h).T).T)
    cos = np.einsum("ij,ij->i", m, unit_rows(a))
    return float(np.degrees(np.arcsin(-np.median(cos))))


class BorderedSystem:
    """The normal equations ``H`` of the joint problem, split once for any damping: a leading
    ``n x n`` block that is block tridiagonal (3x3 blocks, so banded with 5 off-diagonals) and a
    dense border of the last rows and columns. :meth:`solve` takes a banded Cholesky of the
    leading block and the Schur complement of the border (``O(n)``; a general sparse LU fills
    in the border and pivots). Levenberg-Marquardt solves one ``H`` with several dampings.
    """

    def __init__(self, H: object, n: int) -> None:
        from scipy import sparse

        self.H, self.n = sparse.csc_matrix(H), n
        A = self.H[:n, :n]
        self.band = np.zeros((6, n))
        for k in range(6):                          # upper form: row 5 - k holds offset k
            self.band[5 - k, k:] = A.diagonal(k)
        self.E = self.H[:n, n:].toarray()
        self.D = self.H[n:, n:].toarray()
        self.diagonal = self.H.diagonal()

    def solve(self, rhs: np.ndarray, damping: np.ndarray) -> np.ndarray:
        """``(H + diag(damping))^-1 rhs``; the general sparse solve if the damped leading
        block is not positive definite."""
        from scipy.linalg import (
            LinAlgError,
            cho_factor,
            cho_solve,
            cho_solve_banded,
            cholesky_banded,
        )

        n = self.n
        try:
            band = self.band.copy()
            band[5] += damping[:n]
            factor = cholesky_banded(band)
            X = cho_solve_banded((factor, False), np.column_stack([self.E, rhs[:n]]))
            schur = self.D + np.diag(damping[n:]) - self.E.T @ X[:, :-1]
            border = cho_solve(cho_factor(schur), rhs[n:] - self.E.T @ X[:, -1])
            return np.concatenate([X[:, -1] - X[:, :-1] @ border, border])
        except LinAlgError:
            from scipy import sparse
            from scipy.sparse.linalg import spsolve
            return spsolve(self.H + sparse.diags(damping), rhs)


def _solve(Q, p, y, a, w_mid, dt, g_w, weights, max_iter, xtol):
    """Levenberg-Marquardt on the joint problem; returns ``Q, p, iterations, converged``."""
    K = Q.shape[0]
    r, parts = residuals(Q, p, y, a, w_mid, dt, g_w, weights)
    cost, lam = float(r @ r), 1e-6
    for it in range(1, max_iter + 1):
        J = jacobian(Q, p, parts, dt, weights)
        system = BorderedSystem(J.T @ J, 3 * K)
        grad = J.T @ r
        while True:
            step = system.solve(-grad, lam * (system.diagonal + 1e-12))
            Q_new = Q @ rotation_exp(step[:3 * K].reshape(K, 3))
            p_new = p + step[3 * K:]
            r_new, parts_new = residuals(Q_new, p_new, y, a, w_mid, dt, g_w, weights)
            new = float(r_new @ r_new)
            if np.isfinite(new) and new <= cost:
                break
            lam *= 10.0
            if lam > 1e8:
                # No step lowers the cost: a minimum if the gradient is at rounding level.
                scale = np.sqrt(system.diagonal.sum() * cost) or 1.0
                return Q, p, it, bool(np.linalg.norm(grad) <= 1e-6 * scale)
        Q, p, r, parts, cost, lam = Q_new, p_new, r_new, parts_new, new, max(lam / 10.0, 1e-9)
        if np.max(np.abs(step[3 * K:])) <= xtol:
            return Q, p, it, True
    return Q, p, max_iter, False
