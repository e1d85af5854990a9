"""Ali et al. (2012), review section 7, Algorithm 5, eqs. (45)-(48): particle swarm optimisation.

Each particle is a candidate ``x = [h; vec(T^T)]`` (46), i.e. ``h`` followed by the rows of ``T``.
The swarm moves by the velocity and position updates (47) and the answer is the swarm's best
position ``p_g`` (48). The method is gradient-free by design and stays so here: no local
polishing step is added.

Fitness (45)
------------
The review writes ``J = sqrt(sum_k (||y_k||^2 - ||m_k||^2)^2)``: the squared magnitude of the
calibrated field against the squared magnitude of the reference field (Ali et al. compare with
the local geomagnetic field magnitude). With the unit reference field of eq. (2) and the
calibrated field ``m^_k = T^-1 (y_k - h)`` (82) this is ::

    J(T, h) = sqrt( sum_k ( ||T^-1 (y_k - h)||^2 - 1 )^2 ),

the square root of MAG.I.C.AL.'s cost (65), so both methods share their minimiser.

Vectorised evaluation
---------------------
``||T^-1 (y - h)||^2 = [y; 1]^T N [y; 1]`` with the 4x4 matrix ``N = B^T B``,
``B = T^-1 [I, -h]``, so each residual is the dot product of the ten monomials
``phi(y) = [y1^2, y2^2, y3^2, 2 y1 y2, 2 y1 y3, 2 y2 y3, 2 y1, 2 y2, 2 y3, 1]`` with the ten
distinct entries ``c`` of ``N``. With ``Phi`` the ``(K, 10)`` monomial matrix of the samples and
its thin QR factorisation ``Phi = Q R`` (computed once per call),

    J^2 = ||Phi c - 1||^2 = ||R c - Q^T 1||^2 + ||(I - Q Q^T) 1||^2,

exactly, so a whole swarm costs one ``(S, 10) @ (10, 10)`` product per iteration whatever K.
``T^-1`` enters through the cofactor matrix, ``T^-1 = cof(T)^T / det(T)``, so a singular
particle gets an infinite fitness instead of stopping the batch.

PSO coefficients
----------------
The review quotes ``w = 1, c1 = c2 = 2`` and 20 to 65 particles. With ``w = 1`` the update (47)
is an undamped random oscillator whose velocities grow without bound unless clamped, as Kennedy
and Eberhart (1995) did with ``Vmax``; ``variant="classic"`` is that setting with a clamp
``v_max`` (unclamped, 10 nominal runs ended at J (74) ~ 1e9). Its particles keep moving at
about the clamp speed, so the best position it finds is only as fine as the clamp (nominal data,
50 datasets: mean J 3.3e-2 with the default clamp 0.05 r0, 6.5e-3 with 0.01 r0, and only 32 %
meaningful runs with 0.2 r0). ``variant="constriction"``, the
default, uses Clerc and Kennedy's (2002) constriction ``w = 0.7298, c1 = c2 = 1.49618``: the swarm
contracts and finds the minimum of (45) to full precision (mean J 2.49e-3 on the same data, the
value MAG.I.C.AL. reaches; noise-free data to J ~ 1e-10).

Search space ("some prior knowledge of the search space is beneficial", review section 11)
-------------------------------------------------------------------------------------------
On noisy data (45) is not bounded away from zero: a huge sphere through the data,
``T = L I, h = -L u`` with ``||u|| = 1``, gives residuals ``2 u . y_k / L + 1 / L^2``, so a
swarm that wanders far enough finds ever smaller fitness values (the noise-free truth, with
fitness zero, is still the global minimum). Two measures keep the swarm where the answer is:

* ``start="data"`` (default) centres the initial swarm on the centroid of the samples and the
  sphere of their RMS radius ``r0``, and measures ``spread``, ``v_max`` and ``bound`` in units of
  ``r0``; the method is then equivariant under translations and scalings of the data, hence
  insensitive to the size of the hard-iron offset. ``start="identity"`` centres it on
  ``h = 0, T = I`` (the data arrive normalised to about unit magnitude): with the offsets of
  gamma = 1 only 58 % of 50 runs were meaningful, against 100 % from the data centre.
* ``bound`` confines every coordinate to ``centre +- bound * r0`` (clipping, with the velocity
  of a coordinate that hits the wall set to zero), the "constrained search space" the review
  recommends; ``bound=None`` is the unbounded PSO, whose failed runs then drift off until the
  iteration cap instead of stopping at the wall.

A swarm can still settle prematurely on a poor local minimum, as the review warns ("a couple of
repetitions might be needed"): about 1 % of nominal runs with a spread of 0.5, none of 100 with
the default 0.25 (and 92 % meaningful at beta = 0.5 against 72 % with 0.5).
"""

from __future__ import annotations

import numpy as np

from magbench.core.model import Calibration
from magbench.methods.algorithms._jit import njit
from magbench.methods.registry import register

#: (inertia w, cognitive c1, social c2, default velocity clamp) of the two PSO settings.
VARIANTS: dict[str, tuple[float, float, float, float]] = {
    # Review section 7 / Kennedy and Eberhart (1995): diverges without the clamp.
    "classic": (1.0, 2.0, 2.0, 0.05),
    # Clerc and Kennedy (2002) constriction, chi = 0.7298, phi = 4.1; the clamp only guards
    # the first iterations of a badly scaled start.
    "constriction": (0.7298, 1.49618, 1.49618, 1.0),
}

#: Position of ``T[i, j]`` in a particle ``x = [h; vec(T^T)]`` (46): ``3 + 3 i + j``.
_T0 = 3

#: Upper-triangle entries ``(a, b)`` of the 4x4 N, in the order of the monomials of
#: :func:`monomials`.
_N_ROWS = np.array([0, 1, 2, 0, 0, 1, 0, 1, 2, 3])
_N_COLS = np.array([0, 1, 2, 1, 2, 2, 3, 3, 3, 3])


def monomials(samples: np.ndarray) -> np.ndarray:
    """The ``(K, 10)`` monomials ``phi(y)`` with ``||T^-1 (y - h)||^2 = phi(y) . c``."""
    y1, y2, y3 = samples.T
    return np.column_stack([y1 * y1, y2 * y2, y3 * y3, 2 * y1 * y2, 2 * y1 * y3,
                            2 * y2 * y3, 2 * y1, 2 * y2, 2 * y3, np.ones_like(y1)])


@njit
def quadric_coefficients(swarm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unscaled quadric coefficients of every particle and ``det(T)^2``.

    Parameters
    ----------
    swarm : ndarray, shape (S, 12)
        Particles ``[h; vec(T^T)]`` (46).

    Returns
    -------
    c : ndarray, shape (S, 10)
        ``det(T)^2`` times the distinct entries of ``N = T^-1 [I, -h]`` squared (see module
        notes), so that ``||T^-1 (y - h)||^2 = (phi(y) . c) / det(T)^2``.
    det2 : ndarray, shape (S,)
        ``det(T)^2`` (zero for a singular particle).
    """
    S = swarm.shape[0]
    c = np.empty((S, 10))
    det2 = np.empty(S)
    cof = np.empty((3, 3))
    B = np.empty((3, 4))
    for s in range(S):
        x = swarm[s]
        # cofactor(T)[i, j] = T[i+1, j+1] T[i+2, j+2] - T[i+1, j+2] T[i+2, j+1] (indices mod 3)
        for i in range(3):
            i1, i2 = _T0 + 3 * ((i + 1) % 3), _T0 + 3 * ((i + 2) % 3)
            for j in range(3):
                j1, j2 = (j + 1) % 3, (j + 2) % 3
                cof[i, j] = x[i1 + j1] * x[i2 + j2] - x[i1 + j2] * x[i2 + j1]
        det = x[_T0] * cof[0, 0] + x[_T0 + 1] * cof[0, 1] + x[_T0 + 2] * cof[0, 2]
        # det(T) T^-1 [I, -h] = cof^T [I, -h]; its Gram matrix is det^2 N.
        for i in range(3):
            for j in range(3):
                B[i, j] = cof[j, i]
            B[i, 3] = -(cof[0, i] * x[0] + cof[1, i] * x[1] + cof[2, i] * x[2])
        for e in range(10):
            a, b = _N_ROWS[e], _N_COLS[e]
            c[s, e] = B[0, a] * B[0, b] + B[1, a] * B[1, b] + B[2, a] * B[2, b]
        det2[s] = det * det
    return c, det2


@njit
def swarm_fitness(swarm: np.ndarray, Rt: np.ndarray, d: np.ndarray, floor: float
                  ) -> np.ndarray:
    """J (45) of every particle by the QR reduction of the module notes; ``inf`` if T is singular.

    Parameters
    ----------
    swarm : ndarray, shape (S, 12)
        Particles ``[h; vec(T^T)]`` (46).
    Rt, d, floor : ndarray (10, 10), ndarray (10,), float
        ``R^T``, ``Q^T 1`` and ``||(I - Q Q^T) 1||^2`` of the dataset (see :class:`SwarmFitness`).
    """
    c, det2 = quadric_coefficients(swarm)
    J = np.empty(swarm.shape[0])
    for s in range(swarm.shape[0]):
        total = 0.0
        for j in range(10):
            acc = 0.0
            for i in range(10):
                acc += c[s, i] * Rt[i, j]
            r = acc / det2[s] - d[j]
            total += r * r
        J[s] = np.sqrt(total + floor)
        if not np.isfinite(J[s]):
            J[s] = np.inf
    return J


class SwarmFitness:
    """Fitness (45) of a whole swarm for one dataset, by the QR reduction of the module notes."""

    def __init__(self, samples: np.ndarray) -> None:
        Q, R = np.linalg.qr(monomials(samples))
        self.Rt = np.ascontiguousarray(R.T)
        self.d = Q.sum(axis=0)                                       # Q^T 1
        # ||(I - Q Q^T) 1||^2, the part of (45) no quadric can explain, from the residual vector:
        # K - ||Q^T 1||^2 would cancel catastrophically (about 1e-13 absolute, i.e. a false
        # fitness floor of about 3e-7 on noise-free data).
        self.floor = float(np.sum((1.0 - Q @ self.d) ** 2))

    def __call__(self, swarm: np.ndarray) -> np.ndarray:
        """J (45) of every particle of an ``(S, 12)`` swarm; ``inf`` where T is singular."""
        return swarm_fitness(np.ascontiguousarray(swarm, dtype=np.float64), self.Rt, self.d,
                             self.floor)


@njit
def swarm_step(x: np.ndarray, v: np.ndarray, p: np.ndarray, p_fit: np.ndarray,
               g: np.ndarray, g_fit: float, r: np.ndarray, w: float, c1: float, c2: float,
               clamp: float, low: np.ndarray, high: np.ndarray, Rt: np.ndarray,
               d: np.ndarray, floor: float) -> float:
    """Step 3 of Algorithm 5, in place: (47) with clamp and box, fitness, personal and swarm best.

    ``x, v, p, p_fit, g`` are updated in place; ``r`` holds the ``(2, S, 12)`` uniform numbers
    ``r1, r2`` of (47); ``low, high`` bound the box (``-inf, inf`` for none). Returns the new
    swarm-best fitness.
    """
    S, n = x.shape
    for s in range(S):
        for j in range(n):
            # (47a), evaluated in the order NumPy evaluates the vector expression
            vj = w * v[s, j] + c1 * r[0, s, j] * (p[s, j] - x[s, j]) \
                + c2 * r[1, s, j] * (g[j] - x[s, j])
            if vj < -clamp:
                vj = -clamp
            elif vj > clamp:
                vj = clamp
            xj = x[s, j] + vj                                      # (47b)
            # the box: clip, and stop a coordinate that hits the wall
            if xj < low[j]:
                xj, vj = low[j], 0.0
            elif xj > high[j]:
                xj, vj = high[j], 0.0
            x[s, j], v[s, j] = xj, vj
    f = swarm_fitness(x, Rt, d, floor)
    for s in range(S):
        if f[s] < p_fit[s]:
            p[s, :] = x[s, :]
            p_fit[s] = f[s]
    best = np.argmin(p_fit)
    if p_fit[best] < g_fit:
        g[:] = p[best]
        g_fit = p_fit[best]
    return g_fit


def fitness_direct(samples: np.ndarray, T: np.ndarray, h: np.ndarray) -> float:
    """J (45) of one candidate, straight from its definition (the reference for the tests)."""
    m = np.linalg.solve(T, (samples - h).T)
    return float(np.sqrt(np.sum((np.sum(m * m, axis=0) - 1.0) ** 2)))


def split_particle(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``T`` and ``h`` of a particle ``[h; vec(T^T)]`` (48)."""
    return x[_T0:].reshape(3, 3).copy(), x[:_T0].copy()


@register("ali", label="Ali PSO", min_samples=12, randomized=True, paper_key="Ali")
def fit(samples: np.ndarray, *, rng: np.random.Generator, n_particles: int = 40,
        variant: str = "constriction", v_max: float | None = None, spread: float = 0.25,
        bound: float | None = 3.0, start: str = "data", max_iter: int = 3000,
        tol: float = 1e-9, rtol: float = 1e-6, window: int = 100) -> Calibration:
    """Calibrate with the particle swarm of Ali et al. (Algorithm 5).

    Parameters
    ----------
    samples : ndarray, shape (K, 3)
        Measurements ``y_k`` near unit field magnitude.
    rng : numpy.random.Generator
        The only source of randomness (initial swarm and the ``r1, r2`` of (47)).
    n_particles : int
        Swarm size S; the review quotes 20 to 65.
    variant : {"constriction", "classic"}
        PSO coefficients: ``"classic"`` is the review's ``w = 1, c1 = c2 = 2`` (with a velocity
        clamp, without which it diverges); ``"constriction"`` is Clerc and Kennedy's
        ``w = 0.7298, c1 = c2 = 1.49618``, the default because it is the one that converges.
    v_max : float, optional
        Per-coordinate velocity clamp in units of ``r0``; the variant's value (0.05 classic,
        1.0 constriction) if omitted.
    spread : float
        Half-width, in units of ``r0``, of the uniform initial swarm around ``h0, r0 I`` and of
        the uniform initial velocities.
    bound : float or None
        Half-width, in units of ``r0``, of the search box around ``h0, r0 I``; None for none.
    start : {"data", "identity"}
        Centre of the initial swarm and of the box: ``h0`` the centroid of the samples and
        ``r0`` their RMS distance from it, or ``h0 = 0, r0 = 1`` (see :func:`search_centre`).
    max_iter : int
        Iteration cap (stopping rule 2).
    tol : float
        Stop when the best fitness (45) falls below this (stopping rule 1; met on noise-free
        data, never on noisy data, whose fitness has a positive floor).
    rtol, window : float, int
        Stop when the best fitness improved by less than ``rtol`` times its value over the last
        ``window`` iterations (stopping rule 3, "the change of J becomes insignificant").

    Returns
    -------
    Calibration
        ``T`` and ``h`` of the swarm's best position (48); ``converged`` is False when only the
        iteration cap ended the run.
    """
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {', '.join(VARIANTS)}, got {variant!r}")
    if n_particles < 2 or window < 1 or not spread > 0 or (bound is not None and not bound > 0):
        raise ValueError(f"need n_particles >= 2, window >= 1, spread > 0 and bound > 0 or "
                         f"None, got {n_particles}, {window}, {spread}, {bound}")
    w, c1, c2, default_clamp = VARIANTS[variant]
    h0, r0 = search_centre(samples, start)
    clamp = r0 * (default_clamp if v_max is None else float(v_max))
    fitness = SwarmFitness(samples)

    # Step 1: the swarm around h0, r0 I; p_i = x_i.
    centre = np.concatenate([h0, r0 * np.eye(3).ravel()])
    x = centre + r0 * spread * rng.uniform(-1.0, 1.0, size=(n_particles, 12))
    v = r0 * spread * rng.uniform(-1.0, 1.0, size=(n_particles, 12))
    p, p_fit = x.copy(), fitness(x)
    # Step 2: the swarm's best.
    best = int(np.argmin(p_fit))
    g, g_fit = p[best].copy(), float(p_fit[best])
    if bound is None:
        low, high = np.full(12, -np.inf), np.full(12, np.inf)
    else:
        low, high = centre - r0 * bound, centre + r0 * bound

    it, stop, g_fit = run_swarm(rng, x, v, p, p_fit, g, g_fit, w, c1, c2, clamp, low, high,
                                fitness.Rt, fitness.d, fitness.floor, int(max_iter), float(tol),
                                float(rtol), int(window))
    if stop == _STOP_TOL:
        return _result(g, it, True, f"fitness (45) {g_fit:.3g} below tol after {it} iterations")
    if stop == _STOP_STAGNATION:
        return _result(g, it, True, f"fitness (45) {g_fit:.3g} stagnated over {window} "
                                    f"iterations, after {it}")
    return _result(g, max_iter, False, f"iteration cap {max_iter} reached, fitness (45) "
                                       f"{g_fit:.3g}")


#: How :func:`run_swarm` ended: iteration cap (rule 2), fitness below tol (rule 1), stagnation
#: (rule 3).
_STOP_CAP, _STOP_TOL, _STOP_STAGNATION = 0, 1, 2


@njit
def run_swarm(rng: np.random.Generator, x: np.ndarray, v: np.ndarray, p: np.ndarray,
              p_fit: np.ndarray, g: np.ndarray, g_fit: float, w: float, c1: float, c2: float,
              clamp: float, low: np.ndarray, high: np.ndarray, Rt: np.ndarray, d: np.ndarray,
              floor: float, max_iter: int, tol: float, rtol: float, window: int
              ) -> tuple[int, int, float]:
    """Steps 3 and 4 of Algorithm 5, compiled: iterate until one of the three exit conditions.

    ``x, v, p, p_fit, g`` are updated in place (see :func:`swarm_step`). The ``r1, r2`` of (47)
    are drawn from ``rng`` inside the loop: numba's ``Generator.random`` uses the caller's bit
    generator, so these are the numbers, in the order, that ``rng.random((2, S, 12))`` gives
    in Python, and ``rng`` is left in the same state.

    Returns
    -------
    n_iter : int
        Iterations run.
    stop : int
        ``_STOP_TOL``, ``_STOP_STAGNATION`` or ``_STOP_CAP``.
    g_fit : float
        Fitness (45) of the swarm's best position ``g``.
    """
    S = x.shape[0]
    history = np.empty(max_iter + 1)
    history[0] = g_fit
    for it in range(1, max_iter + 1):
        r = rng.random((2, S, 12))
        g_fit = swarm_step(x, v, p, p_fit, g, g_fit, r, w, c1, c2, clamp, low, high, Rt, d,
                           floor)
        history[it] = g_fit
        # Step 4: the three exit conditions.
        if g_fit <= tol:
            return it, _STOP_TOL, g_fit
        if it >= window and history[it - window] - g_fit <= rtol * history[it - window]:
            return it, _STOP_STAGNATION, g_fit
    return max_iter, _STOP_CAP, g_fit


def search_centre(samples: np.ndarray, start: str) -> tuple[np.ndarray, float]:
    """Centre ``h0`` and scale ``r0`` of the initial swarm (``T`` around ``r0 I``).

    ``"data"``: the centroid of the samples and their RMS distance from it, the sphere the data
    suggest before any fitting; ``"identity"``: ``h0 = 0, r0 = 1``.
    """
    if start == "identity":
        return np.zeros(3), 1.0
    if start == "data":
        h0 = samples.mean(axis=0)
        return h0, float(np.sqrt(np.mean(np.sum((samples - h0) ** 2, axis=1))))
    raise ValueError(f"start must be 'data' or 'identity', got {start!r}")


def _result(g: np.ndarray, n_iter: int, converged: bool, message: str) -> Calibration:
    """Step 5: T and h from the swarm's best position (48)."""
    T, h = split_particle(g)
    return Calibration(T, h, n_iter, converged, message)
