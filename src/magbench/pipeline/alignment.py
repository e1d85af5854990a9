"""Direction for ``calibrate``: the alignment of a chosen calibration to the inertial sensors,
its held-out direction consistency, the direction veto and the geomagnetic check.

A calibration chosen on field magnitude (:mod:`magbench.pipeline.calibration`) fixes ``T`` only up
to a rotation; its symmetric gauge gives field directions ``A (y - h)``. With inertial columns
the rotation ``R`` to the IMU's axes is fitted here (:func:`fit_alignment`), from the strongest
source the recording holds:

* ``attitude`` (a reference orientation, sensor -> world): the rotation and the world field
  direction that best explain ``R A (y_k - h) = Q_k^T m_w`` (Wahba's problem, alternated with
  the mean world direction);
* ``gyro`` and ``accelerometer``: the joint MAP of ``mag_imu_map`` (orientation trajectory
  unknown), whose field in IMU axes is matched by a rotation (Procrustes);
* ``accelerometer`` alone, at several rests: the dip constraint of ``dip_align``.

:func:`direction_consistency` scores any calibration on held-out rows by
:func:`magbench.core.direction.direction_score` (heading and inclination errors and field
spread with an attitude, gyro consistency, dip spread at rest); :func:`direction_vetoes` names
the candidates whose direction is worse than the best by more than a tolerance, so that a fit
that improves magnitude but worsens direction is not chosen; :func:`field_check` sets a fit
beside the geomagnetic model at the user's site.
"""

from __future__ import annotations

import datetime as dt
import functools
import hashlib
import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from magbench.core import geometry
from magbench.core.blockwise import affine_rows, halo, mean_direction_rows
from magbench.core.direction import direction_score, mean_direction, world_field
from magbench.core.gauge import safe_gauge
from magbench.core.geomagnetic import ExpectedField, Site, expected_field
from magbench.core.geometry import sphere_fit
from magbench.core.lag import attitude_rate, magnetometer_lag, shift
from magbench.core.model import Calibration, CalibrationFailed
from magbench.core.offsets import (
    OffsetSegment,
    consistent_rows,
    gyro_orientation,
    offset_segments,
    window_offsets,
)
from magbench.core.quaternions import (
    MatrixView,
    UnitRows,
    blocks,
    finite_rows,
    quat_span_deg,
    quat_to_matrix,
    unit_quaternions,
)
from magbench.core.units import infer_units
from magbench.methods.algorithms._alignment_common import (
    check_spread,
    dip_rotation,
    nearest_rotation,
    refine_dip_rotation,
    static_rows,
    unit_rows,
)
from magbench.methods.api import calibrate
from magbench.pipeline.flight import compact_rows
from magbench.pipeline.holdout import estimate, fold_indices
from magbench.sources.recordings import Recording

__all__ = [
    "PRIMARY",
    "DirectionReport",
    "DirectionVeto",
    "Inertial",
    "OffsetCheck",
    "align_chosen",
    "attitude_profile",
    "attitude_turn_deg",
    "attitude_view",
    "direction_consistency",
    "direction_report",
    "direction_vetoes",
    "field_check",
    "fit_alignment",
    "fold_direction",
    "inertial_of",
    "inertial_source",
    "lag_corrected",
    "most_turning_run",
    "offset_check",
    "primary_direction",
]


#: Fewest rows with a finite attitude for the alignment to take its rotation from them.
MIN_ATTITUDE_ROWS = 10


@dataclass(frozen=True)
class Inertial:
    """Inertial streams beside the magnetometer samples, on the same rows (any may be None).

    ``t`` in s, ``gyro`` in rad/s and ``acceleration`` (specific force) in the IMU's axes,
    ``attitude`` unit quaternions scalar first, sensor -> world (NaN rows allowed): an array,
    or a :class:`~magbench.core.quaternions.UnitRows` that normalises rows as read.
    """

    t: np.ndarray | None = None
    gyro: np.ndarray | None = None
    acceleration: np.ndarray | None = None
    attitude: np.ndarray | None = None

    def rows(self, index: slice | np.ndarray) -> Inertial:
        """The streams restricted to some rows."""
        return Inertial(*(None if v is None else v[index]
                          for v in (self.t, self.gyro, self.acceleration, self.attitude)))

    @property
    def source(self) -> str:
        """What :func:`fit_alignment` will use: ``attitude``, ``gyro+accelerometer``,
        ``accelerometer`` or ``none``."""
        finite = 0 if self.attitude is None else int(finite_rows(self.attitude).sum())
        return _source(finite, self.t, self.gyro, self.acceleration is not None)


def symmetric_field(cal: Calibration, y: np.ndarray) -> np.ndarray:
    """``A (y - h)``: the calibrated field in the symmetric gauge (what an alignment turns)."""
    return (y - cal.h) @ safe_gauge(cal.T, cal.h).A.T


#: Least turn of the attitude (deg) that fixes the magnetometer's rotation: a calibration
#: recording turns through far more; less means a frozen or unrelated attitude stream.
MIN_ATTITUDE_SPAN_DEG = 30.0


def _finite_rows(x: np.ndarray) -> np.ndarray:
    """The rows of ``x`` without NaN: ``x`` itself (no copy) when every row is finite."""
    ok = np.isfinite(x).all(axis=1)
    return x if ok.all() else x[ok]


def attitude_turn_deg(attitude: np.ndarray | UnitRows, use: np.ndarray | None = None
                      ) -> float:
    """How far an attitude stream (``(K, 4)`` quaternions or a
    :class:`~magbench.core.quaternions.UnitRows`, NaN rows allowed) turns: the largest angle
    between its first finite row and any other, deg (0 without a finite row). ``use``: only
    these rows (a mask; each must be finite)."""
    if isinstance(attitude, np.ndarray) and use is None:
        return quat_span_deg(_finite_rows(attitude))     # a block at a time: no (K, 3, 3)
    # a block of rows read at a time, each block's rows measured from the first used row
    first, turned = None, 0.0
    for b in blocks(len(attitude)):
        q = attitude[b]
        q = _finite_rows(q) if use is None else q[use[b]]
        if len(q):
            first = q[:1] if first is None else first
            turned = max(turned, quat_span_deg(np.concatenate([first, q])))
    return turned


def wahba_alignment(m: np.ndarray, attitude: np.ndarray, n_iter: int = 10, *,
                    overwrite: bool = False) -> np.ndarray:
    """The rotation ``R`` with ``R m_k`` nearest ``Q_k^T m_w`` for the best world direction
    ``m_w``: alternate the mean world direction and Wahba's solution (SVD).

    ``overwrite``: ``m`` (a fresh array) may be made its own unit rows in place, the same
    numbers without a second ``(K, 3)`` array.

    Raises :class:`CalibrationFailed` when the attitude turns through less than
    :data:`MIN_ATTITUDE_SPAN_DEG`: the reference directions are then nearly one, which fixes
    no rotation (a frozen or wrong attitude stream beside a magnetometer that turned)."""
    _check_turn(attitude)
    ok = finite_rows(attitude)
    if overwrite:                       # unit_rows(m[ok]): the rows moved up, divided in place
        u = m if ok.all() else compact_rows(m, ok)
        u = _unit_in_place(u)
    else:
        u = unit_rows(m if ok.all() else m[ok])
    del m
    return _wahba(u, attitude, ok, n_iter)


def _check_turn(attitude: np.ndarray | UnitRows, use: np.ndarray | None = None) -> None:
    """:class:`CalibrationFailed` when the ``use`` rows of the attitude turn through less
    than :data:`MIN_ATTITUDE_SPAN_DEG`."""
    turned = attitude_turn_deg(attitude, use)
    if turned < MIN_ATTITUDE_SPAN_DEG:
        raise CalibrationFailed(f"the attitude turned through {turned:.0f} deg (< "
                                f"{MIN_ATTITUDE_SPAN_DEG:g}): it cannot fix the rotation")


def _unit_in_place(u: np.ndarray) -> np.ndarray:
    """The rows of ``u`` (a fresh array) made unit in place: :func:`unit_rows`'s numbers."""
    return np.divide(u, np.sqrt(np.einsum("ij,ij->i", u, u))[:, None], out=u)


def _parts(attitude: np.ndarray | UnitRows, use: np.ndarray) -> list[tuple[slice, slice]]:
    """Each block of the attitude's rows and the rows of its used ones among all used rows."""
    parts, n = [], 0
    for b in blocks(len(attitude)):
        k = int(use[b].sum())
        parts.append((b, slice(n, n + k)))
        n += k
    return parts


def _matrices(attitude: np.ndarray | UnitRows, use: np.ndarray, b: slice) -> np.ndarray:
    """The rotation matrices of the used rows of block ``b`` of the attitude."""
    q = attitude[b]
    return quat_to_matrix(q if use[b].all() else q[use[b]])


def attitude_profile(u: np.ndarray, attitude: np.ndarray | UnitRows, use: np.ndarray,
                     m_w: np.ndarray) -> np.ndarray:
    """Wahba's attitude profile matrix ``B = sum_k r_k u_k^T``, ``r_k = Q_k^T m_w`` the world
    direction ``m_w`` in body axes at the ``use`` rows of ``attitude`` and ``u`` their
    body directions (in order), summed a chunk of at most
    :data:`magbench.core.geometry.BLOCK_ROWS` rows at a time: the reference directions of
    one chunk are held, not of every row. With no more rows than that, one product over
    every row (the whole array's numbers); else the chunks' products added in order (a sum
    in another order: round-off)."""
    parts = _parts(attitude, use)
    return _profile(u, parts, functools.partial(_matrices, attitude, use), m_w)


def _profile(u: np.ndarray, parts: list[tuple[slice, slice]],
             matrices: Callable[[slice], np.ndarray], m_w: np.ndarray) -> np.ndarray:
    """:func:`attitude_profile` over ``parts`` (:func:`_parts`), ``matrices(b)`` the used rows'
    rotation matrices of block ``b``."""
    chunks: list[list[tuple[slice, slice]]] = []
    for b, r in parts:
        if chunks and r.stop - chunks[-1][0][1].start <= geometry.BLOCK_ROWS:
            chunks[-1].append((b, r))
        else:
            chunks.append([(b, r)])
    spans = [slice(c[0][1].start, c[-1][1].stop) for c in chunks]
    rows = np.empty((max(s.stop - s.start for s in spans), 3))
    B = np.zeros((3, 3))
    for chunk, span in zip(chunks, spans, strict=True):
        for b, r in chunk:
            rows[r.start - span.start:r.stop - span.start] = np.einsum(
                "kji,j->ki", matrices(b), m_w)
        part = rows[:span.stop - span.start].T @ u[span]
        B = part if len(spans) == 1 else B + part
    return B


def _wahba(u: np.ndarray, attitude: np.ndarray | UnitRows, use: np.ndarray,
           n_iter: int) -> np.ndarray:
    """:func:`wahba_alignment`'s iterations: ``u`` the unit body directions of the ``use``
    rows of ``attitude`` (in order), which are finite. The used rows' matrices are made a
    block of the attitude at a time in each pass (a long log's ``(K, 3, 3)`` would be three
    times its samples); the world directions are only summed (their mean), the reference
    directions in body axes a chunk at a time (:func:`attitude_profile`). An attitude of
    one block has its matrices made once, for every pass."""
    parts = _parts(attitude, use)
    held = _matrices(attitude, use, parts[0][0]) if len(parts) == 1 else None

    def matrices(b: slice) -> np.ndarray:
        return held if held is not None else _matrices(attitude, use, b)

    R = np.eye(3)
    for _ in range(n_iter):
        m_w = mean_direction_rows(np.einsum("kij,kj->ki", matrices(b), u[r] @ R.T)
                                  for b, r in parts)
        R = nearest_rotation(_profile(u, parts, matrices, m_w))
    return R


def fit_alignment(cal: Calibration, y: np.ndarray, inertial: Inertial,
                  **map_options: object) -> tuple[Calibration, str]:
    """The chosen calibration with its rotation to the IMU, and what fixed it.

    Parameters
    ----------
    cal : Calibration
        The calibration chosen on magnitude (any gauge).
    y : ndarray, shape (K, 3)
        The magnetometer samples it was fitted on.
    inertial : Inertial
        The streams on the same rows.
    **map_options
        Options of ``mag_imu_map`` (noise levels) for the gyro+accelerometer source.

    Returns
    -------
    Calibration
        ``cal`` in the symmetric gauge with ``alignment`` set (heading-true).
    str
        The source: ``attitude``, ``gyro+accelerometer`` or ``accelerometer``.

    Raises
    ------
    CalibrationFailed
        No inertial stream, or one that cannot fix the rotation (rests too alike).
    """
    safe = cal.safe()
    source = inertial.source
    if source == "attitude":            # a fresh field: its unit rows made in place
        R = wahba_alignment(symmetric_field(safe, y), inertial.attitude, overwrite=True)
    elif source == "gyro+accelerometer":
        m = symmetric_field(safe, y)
        joint = calibrate(y, "mag_imu_map", angular_rate=inertial.gyro, time=inertial.t,
                          acceleration=inertial.acceleration, **map_options)
        if not joint.converged:
            raise CalibrationFailed(f"alignment: the joint gyro and accelerometer fit did not "
                                    f"converge ({joint.message}); the rotation is unknown")
        A, b = joint.correction()                        # heading-true: the IMU's axes
        R = nearest_rotation(unit_rows((y - b) @ A.T).T @ unit_rows(m))
    elif source == "accelerometer":
        m = symmetric_field(safe, y)
        rows = static_rows(inertial.acceleration, 0.05)
        up = unit_rows(inertial.acceleration[rows])
        check_spread(up, 0.02)
        R, _, _ = refine_dip_rotation(unit_rows(m[rows]), up,
                                      dip_rotation(unit_rows(m[rows]), up)[0])
    else:
        raise CalibrationFailed("alignment: no accelerometer, gyro or attitude columns; the "
                                "rotation to the IMU is unknown (symmetric gauge)")
    return Calibration(safe.T, safe.h, cal.n_iter, cal.converged, cal.message, cal.gyro_bias,
                       R), source


def direction_consistency(cal: Calibration, y: np.ndarray, inertial: Inertial, *,
                          reference: np.ndarray | None = None) -> dict[str, float]:
    """Direction metrics of ``cal`` on (held-out) rows, in degrees.

    The field is ``cal``'s correction in its own gauge (heading-true when it has an alignment,
    which the gyro consistency and dip spread need). With an attitude and no ``reference``
    the world field direction is its own mean on these rows (the heading error is then a
    spread about the mean heading); pass the fit rows' mean for a true held-out error.

    Returns
    -------
    dict
        :func:`magbench.core.direction.direction_score`'s keys.
    """
    A, b = cal.correction()
    field = (y - b) @ A.T
    if inertial.attitude is not None and reference is None:
        ok = np.isfinite(inertial.attitude).all(axis=1)
        reference = mean_direction(world_field(field[ok], inertial.attitude[ok]))
    return direction_score(field, attitude=inertial.attitude, reference=reference,
                           t=inertial.t, angular_rate=inertial.gyro,
                           acceleration=inertial.acceleration)


def world_reference(cal: Calibration, y: np.ndarray, attitude: np.ndarray) -> np.ndarray:
    """The mean world-frame field direction of ``cal`` on the fit rows (the held-out rows'
    heading error is measured against it)."""
    A, b = cal.correction()
    ok = np.isfinite(attitude).all(axis=1)
    return mean_direction(world_field((y[ok] - b) @ A.T, attitude[ok]))


def direction_vetoes(direction_deg: dict[str, float], tol_deg: float = 1.0,
                     tol_share: float = 0.1, among: Collection[str] | None = None
                     ) -> dict[str, str]:
    """Candidates whose held-out direction error exceeds the best one's by more than
    ``max(tol_deg, tol_share * best)``, each with the reason (a candidate with a NaN score is
    not vetoed).

    Parameters
    ----------
    direction_deg : dict
        Candidate name -> its held-out direction error (e.g. heading RMS or gyro RMS), deg.
    tol_deg, tol_share : float
        What the direction may lose to the best before a candidate is set aside: degrees, or
        a share of the best's error when that is larger (a held-out error of 40 deg is not
        known to 1 deg).
    among : collection of str, optional
        The candidates that could be chosen on every other ground: the best is sought among
        them (a fit the choice could never take must not set the others aside); among all
        when none of them has a score.
    """
    finite = {k: v for k, v in direction_deg.items() if math.isfinite(v)}
    if not finite:
        return {}
    pool = {k: v for k, v in finite.items() if among is None or k in among} or finite
    best_name = min(pool, key=pool.get)
    best = pool[best_name]
    limit = best + max(tol_deg, tol_share * best)
    return {k: f"held-out direction error {v:.2f} deg, {v - best:.2f} deg worse than "
               f"{best_name}'s {best:.2f} deg"
            for k, v in finite.items() if v > limit}


def field_check(strength: float, inclination_deg: float | None, site: Site, date: dt.date,
                *, strength_tol: float = 0.1, inclination_tol_deg: float = 3.0) -> dict:
    """A fit's field strength (recorded units) and inclination beside the geomagnetic model.

    Returns
    -------
    dict
        ``expected`` (:class:`ExpectedField`), ``unit`` (the unit in which the strength
        matches the model within 25 %, or None for raw counts), ``strength_ratio`` (measured
        over expected, in that unit; NaN without one), ``inclination_error_deg`` (NaN without
        an inclination) and ``ok`` with ``reasons`` for what is off.
    """
    expected: ExpectedField = expected_field(site, date)
    units = infer_units(strength, expected.strength_gauss)
    ratio = strength * units.gauss / expected.strength_gauss if units.known else math.nan
    incl_err = (inclination_deg - expected.inclination_deg if inclination_deg is not None
                else math.nan)
    reasons = []
    if not units.known:
        reasons.append(f"field strength {strength:.4g} matches the model's "
                       f"{expected.strength_nT:.0f} nT in no unit (raw counts?)")
    elif abs(ratio - 1.0) > strength_tol:
        reasons.append(f"field strength {ratio:.2f} times the model's "
                       f"{expected.strength_gauss / units.gauss:.4g} {units.name}")
    if abs(incl_err) > inclination_tol_deg:
        reasons.append(f"inclination {inclination_deg:.1f} deg against the model's "
                       f"{expected.inclination_deg:.1f} deg")
    return {"expected": expected, "unit": units.name or None, "strength_ratio": ratio,
            "inclination_error_deg": incl_err, "ok": not reasons, "reasons": reasons}


#: The held-out direction metric that rules the veto, strongest first: heading error against
#: an attitude, consistency with the gyro, spread of the dip angle at rest.
PRIMARY = (("heading_rms", "held-out heading RMS"), ("gyro_rms", "gyro consistency RMS"),
           ("dip_spread", "dip-angle spread at rest"))


def primary_direction(score: dict[str, float]) -> tuple[str, float]:
    """The first metric of :data:`PRIMARY` that ``score`` holds (finite), as (label, deg);
    ``("", nan)`` when none."""
    for key, label in PRIMARY:
        value = score.get(key, math.nan)
        if math.isfinite(value):
            return label, float(value)
    return "", math.nan


@dataclass(frozen=True)
class DirectionReport:
    """What ``calibrate`` prints and writes about direction.

    Attributes
    ----------
    aligned : dict
        Candidate name -> its calibration made heading-true on the fit rows (candidates whose
        alignment failed are left out).
    scores : dict
        Candidate name -> :func:`direction_consistency` on the held-out rows.
    metric : str
        The label of the metric that rules the veto (:func:`primary_direction`).
    vetoes : dict
        Candidate name -> why it is set aside (:func:`direction_vetoes`).
    source : str
        What fixed the alignment (``attitude``, ``gyro+accelerometer``, ``accelerometer``).
    failures : dict
        Candidate name -> why its alignment failed.
    """

    aligned: dict
    scores: dict
    metric: str
    vetoes: dict
    source: str
    failures: dict

    def line(self, name: str) -> str:
        """One line on ``name``'s direction, for the printed report."""
        if name in self.failures:
            return f"{name}: direction not measured ({self.failures[name]})"
        label, value = primary_direction(self.scores[name])
        veto = f"; set aside: {self.vetoes[name]}" if name in self.vetoes else ""
        return f"{name}: {label} {value:.2f} deg (alignment from {self.source}){veto}"


def direction_report(candidates: dict[str, Calibration], y: np.ndarray, inertial: Inertial,
                     fit: np.ndarray, test: np.ndarray, *, tol_deg: float = 1.0,
                     **map_options: object) -> DirectionReport:
    """Align every candidate on the fit rows, score it on the held-out rows, veto.

    Parameters
    ----------
    candidates : dict
        Name -> calibration chosen on magnitude (fitted on ``fit`` rows).
    y : ndarray, shape (K, 3)
        All magnetometer samples; ``inertial`` on the same rows.
    fit, test : ndarray of int
        Row indices of the fit and held-out parts (the gyro+accelerometer source needs
        ``fit`` to be consecutive rows).
    tol_deg : float
        See :func:`direction_vetoes`.
    """
    aligned, scores, failures, source = {}, {}, {}, inertial.source
    for name, cal in candidates.items():
        try:
            aligned[name], source = fit_alignment(cal, y[fit], inertial.rows(fit),
                                                  **map_options)
        except CalibrationFailed as exc:
            failures[name] = str(exc)
            continue
        reference = (world_reference(aligned[name], y[fit], inertial.attitude[fit])
                     if source == "attitude" else None)
        scores[name] = direction_consistency(aligned[name], y[test], inertial.rows(test),
                                             reference=reference)
    primary = {n: primary_direction(s) for n, s in scores.items()}
    metric = next((label for label, _ in primary.values() if label), "")
    vetoes = direction_vetoes({n: v for n, (_, v) in primary.items()}, tol_deg)
    return DirectionReport(aligned, scores, metric, vetoes, source, failures)


#: Recording columns of the inertial streams beside ``t`` and the gyro.
ATTITUDE_COLUMNS = ["qw", "qx", "qy", "qz"]
ACCEL_COLUMNS = ["ax", "ay", "az"]
#: Longest run of consecutive rows the joint gyro+accelerometer fit is given (its cost grows
#: with the rows; a minute at 50 Hz fixes the rotation well).
MAX_JOINT_ROWS = 3000


def inertial_of(rec: Recording) -> Inertial:
    """The inertial streams of a recording: its times and gyro, and the attitude
    (``qw..qz``) and accelerometer (``ax..az``) columns it holds in ``extra``."""
    def columns(names: list[str]) -> np.ndarray | None:
        if rec.extra is None or not all(c in rec.extra for c in names):
            return None
        return rec.stack(names)

    attitude = columns(ATTITUDE_COLUMNS)
    return Inertial(rec.t, rec.gyro, columns(ACCEL_COLUMNS),
                    None if attitude is None else unit_quaternions(attitude))


def attitude_view(rec: Recording) -> UnitRows | None:
    """:func:`inertial_of`'s attitude as a view that normalises rows as read (the same
    numbers, row by row, without the ``(K, 4)`` copy); None without attitude columns."""
    if rec.extra is None or not all(c in rec.extra for c in ATTITUDE_COLUMNS):
        return None
    return UnitRows([rec.extra[c] for c in ATTITUDE_COLUMNS])


def inertial_source(rec: Recording) -> str:
    """``inertial_of(rec).source``, with the attitude's finite rows counted a block at a time
    (no normalised ``(K, 4)`` copy of a long log's attitude)."""
    attitude = attitude_view(rec)
    finite = 0 if attitude is None else int(finite_rows(attitude).sum())
    accel = rec.extra is not None and all(c in rec.extra for c in ACCEL_COLUMNS)
    return _source(finite, rec.t, rec.gyro, accel)


def _source(attitude_rows: int, t: np.ndarray | None, gyro: np.ndarray | None,
            acceleration: bool) -> str:
    """:attr:`Inertial.source` from what it depends on: the rows with a finite attitude (at
    least :data:`MIN_ATTITUDE_ROWS` to fix a rotation), the times, the gyro and whether an
    accelerometer is present."""
    if attitude_rows >= MIN_ATTITUDE_ROWS:
        return "attitude"
    if gyro is not None and t is not None and acceleration:
        return "gyro+accelerometer"
    return "accelerometer" if acceleration else "none"


def fold_direction(trials: Sequence[Mapping], work: Recording, name: str,
                   inertial: Inertial) -> float:
    """Held-out heading RMS (deg) of ``name`` over the folds of ``trials``: each fold's fit is
    aligned by the attitude on its training rows and scored on its test rows, against the
    training rows' world direction; NaN unless every fold's fit is usable."""
    rows = [r for r in trials if r["algorithm"] == name and r["fit_on"] != "all"]
    if len(rows) < 2 or not all(bool(r["usable"]) for r in rows):
        return math.nan
    squares = []
    for f, test in enumerate(fold_indices(work.K, len(rows))):
        T, h = estimate(next(r for r in rows if r["fit_on"] == f"fold{f}"))
        train = np.setdiff1d(np.arange(work.K), test)
        try:
            aligned, _ = fit_alignment(Calibration(T, h), work.y[train], inertial.rows(train))
        except (CalibrationFailed, ValueError, np.linalg.LinAlgError):
            return math.nan
        reference = world_reference(aligned, work.y[train], inertial.attitude[train])
        score = direction_consistency(aligned, work.y[test], inertial.rows(test),
                                      reference=reference)
        squares.append(score["heading_rms"] ** 2)
    return float(np.sqrt(np.mean(squares)))


class DirectionVeto:
    """The ``extra`` score of :func:`magbench.pipeline.calibration.calibrate_recording`: with
    a reference attitude, every candidate's held-out heading RMS over the same folds as the
    magnitude score; a candidate worse than the best that could be chosen (``choosable``) by more
    than the tolerance (:func:`direction_vetoes`) is scored NaN, so it is not eligible (a fit
    that improves magnitude but worsens direction is not chosen), the others 1 (they tie).
    ``scores`` and ``vetoes`` keep the last call's numbers to print."""

    column = "direction_ok"

    def __init__(self, tol_deg: float = 1.0):
        self.tol_deg = tol_deg
        self.scores: dict[str, float] = {}
        self.vetoes: dict[str, str] = {}
        # A second round ranks the first round's candidates again on the same folds: their
        # scores are kept, keyed by the samples and the fold fits they come from.
        self._known: dict[tuple, float] = {}

    def _score(self, trials: Sequence[Mapping], work: Recording, name: str,
               inertial: Inertial, samples: bytes) -> float:
        folds = tuple((r["fit_on"], *(a.tobytes() for a in estimate(r)))
                      for r in trials if r["algorithm"] == name and r["fit_on"] != "all")
        key = (samples, name, folds)
        if key not in self._known:
            self._known[key] = fold_direction(trials, work, name, inertial)
        return self._known[key]

    def __call__(self, summary: Sequence[Mapping], trials: Sequence[Mapping],
                 work: Recording) -> tuple[str, list[float]]:
        names = [str(r["algorithm"]) for r in summary]
        inertial = inertial_of(work)
        if inertial.source != "attitude":
            return self.column, [1.0] * len(names)
        attitude_only = Inertial(attitude=inertial.attitude)
        samples = hashlib.sha256(np.ascontiguousarray(work.y).tobytes()
                                 + np.ascontiguousarray(inertial.attitude).tobytes()).digest()
        self.scores = {n: self._score(trials, work, n, attitude_only, samples) for n in names}
        among = {n for n, r in zip(names, summary, strict=True) if r.get("choosable", True)}
        self.vetoes = direction_vetoes(self.scores, self.tol_deg, among=among)
        return self.column, [math.nan if n in self.vetoes else 1.0 for n in names]


def most_turning_run(keep: np.ndarray, t: np.ndarray, gyro: np.ndarray,
                     limit: int) -> np.ndarray:
    """Indices of at most ``limit`` consecutive ``True`` rows of ``keep`` that turn the most
    (the largest sum of ``|gyro| dt``): a joint fit's gyro chain needs consecutive rows, and
    a rest before take-off or between moves fixes no rotation. Of equal windows, the first."""
    K = len(keep)
    turn = np.zeros(K)                  # the turn from row k to row k + 1, at row k's rate
    turn[:-1] = np.linalg.norm(gyro[:-1], axis=1) * np.diff(t)
    turned = np.concatenate([[0.0], np.cumsum(np.nan_to_num(turn))])
    edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(int), [0]])))
    best = (-1.0, 0, 0)
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        n = min(limit, stop - start)
        first = np.arange(start, stop - n + 1)
        total = turned[first + n - 1] - turned[first]
        j = int(np.flatnonzero(total >= total.max() - 1e-9 * abs(total.max()))[0])
        if total[j] > best[0] + 1e-9 * abs(best[0]):
            best = (float(total[j]), int(first[j]), n)
    return np.arange(best[1], best[1] + best[2])


def align_chosen(cal: Calibration, rec: Recording, keep: np.ndarray,
                 **map_options: object) -> tuple[Calibration, str]:
    """The chosen calibration made heading-true on the recording's kept rows (every kept row
    for an attitude or accelerometer; for the gyro+accelerometer fit, whose gyro chain needs
    consecutive rows, the :data:`MAX_JOINT_ROWS` of them that turn the most). The joint fit
    takes hand-held noise levels and the accelerometer as calibrated (a flight controller's
    firmware calibrates it; a free bias soaks up linear accelerations)."""
    keep = np.asarray(keep, dtype=bool)
    attitude = attitude_view(rec)
    if attitude is not None:
        use = keep & finite_rows(attitude)
        if use.sum() >= MIN_ATTITUDE_ROWS:     # the attitude fixes it: a block at a time
            return _attitude_alignment(cal, rec.y, attitude, keep, use), "attitude"
    inertial = inertial_of(rec)
    rows = slice(None) if keep.all() else np.flatnonzero(keep)      # views when all kept
    if inertial.source == "gyro+accelerometer":
        rows = most_turning_run(keep, rec.t, rec.gyro, MAX_JOINT_ROWS)
        map_options = {"sigma_acc": 0.2, "sigma_gyro": 0.05, "accel_bias": False,
                       **map_options}
        return fit_alignment(cal, rec.y[rows], inertial.rows(rows), **map_options)
    # the normalised attitude is inertial_of's own copy: its kept rows are moved to its front
    # rather than copied (a long log's (K, 4) array)
    attitude = inertial.attitude
    if attitude is not None and not isinstance(rows, slice):
        attitude = compact_rows(attitude, keep)
    else:
        attitude = None if attitude is None else attitude[rows]
    inertial = replace(inertial.rows(rows) if inertial.attitude is None else
                       replace(inertial, attitude=None).rows(rows), attitude=attitude)
    return fit_alignment(cal, rec.y[rows], inertial, **map_options)


def _attitude_alignment(cal: Calibration, y: np.ndarray, attitude: UnitRows, keep: np.ndarray,
                        use: np.ndarray) -> Calibration:
    """:func:`fit_alignment` by the attitude on the ``keep`` rows (``use``: those of them
    with a finite attitude) without a copy of the kept samples, their field or the
    normalised attitude: the unit field of the used rows is the one array of their size,
    made :data:`magbench.core.geometry.BLOCK_ROWS` rows at a time (each chunk's field made
    from its kept rows, then its rows without attitude dropped, as the whole array's was);
    one chunk, the whole array's numbers, when there are no more rows."""
    safe = cal.safe()
    _check_turn(attitude, use)
    u = np.empty((int(use.sum()), 3))
    n = 0
    for b in blocks(len(y), geometry.BLOCK_ROWS):
        every = keep[b].all()
        field = symmetric_field(safe, y[b] if every else y[b][keep[b]])
        ok = use[b] if every else use[b][keep[b]]
        field = _unit_in_place(field if ok.all() else field[ok])
        u[n:n + len(field)] = field
        n += len(field)
    R = _wahba(u, attitude, use, 10)
    return Calibration(safe.T, safe.h, cal.n_iter, cal.converged, cal.message, cal.gyro_bias, R)


def _attitude_rate(rec: Recording) -> np.ndarray:
    """:func:`magbench.core.lag.attitude_rate` of the recording's normalised attitude, that
    attitude made a block of rows (and their two neighbours) at a time: the same numbers
    without its ``(K, 4)`` copy."""
    K, attitude = rec.K, attitude_view(rec)
    out = np.empty((K, 3))
    for rows in blocks(K):
        near = halo(rows, K)
        out[rows] = attitude_rate(rec.t[near], attitude[near])[
            rows.start - near.start:rows.stop - near.start]
    return out


def _reusable(y: object) -> bool:
    """Whether ``y`` is a writeable float64 array in one contiguous block of memory (either
    order), which :func:`lag_corrected` may overwrite."""
    return (isinstance(y, np.ndarray) and y.dtype == np.float64 and y.flags.writeable
            and (y.flags.c_contiguous or y.flags.f_contiguous))


def lag_corrected(rec: Recording, max_lag_s: float = 0.1, *, in_place: bool = False
                  ) -> tuple[Recording, float]:
    """The recording with its magnetometer moved onto the inertial streams' times, and the
    lag removed (s; positive: the magnetometer reads late), measured against the attitude's
    rate (or the gyro's) by :func:`magbench.core.lag.magnetometer_lag` on the field centred by
    a sphere fit. Unchanged (lag 0) without times and a rate stream, or when no lag is found; rows
    the shift leaves without a value are dropped. ``in_place``: the moved field is written
    over ``rec.y``'s memory when that array allows it (a caller that keeps only the result
    then holds one copy of a long log's samples after the shift, not two); ``rec`` is not to
    be used afterwards."""
    has_attitude = attitude_view(rec) is not None
    if rec.t is None or (not has_attitude and rec.gyro is None):
        return rec, 0.0
    rate = _attitude_rate(rec) if has_attitude else rec.gyro
    # the field centred a block at a time in the lag fit of a long log: no (K, 3) copy
    lag, _ = magnetometer_lag(rec.t, rec.y, rate, max_lag_s, centre=sphere_fit(rec.y)[0])
    del rate                            # a (K, 3) array not held beside the shift's result
    if not np.isfinite(lag) or lag == 0.0:
        return rec, 0.0
    y = shift(rec.t, rec.y, lag)
    if in_place and _reusable(rec.y):
        # the read samples' memory takes the result in the copy's own (row) layout, which
        # NumPy's and BLAS's sums follow: the same numbers as the copy, one copy held after
        moved, y = y, rec.y.ravel(order="K").reshape(y.shape)
        y[...] = moved
        del moved
    keep = np.flatnonzero(np.isfinite(y).all(axis=1))
    if keep.size and keep[-1] - keep[0] + 1 == keep.size:
        keep = slice(keep[0], keep[-1] + 1)         # the shift cuts the ends only: views
    return replace(rec, y=y).rows(keep), float(lag)


@dataclass(frozen=True)
class OffsetCheck:
    """Whether the hard-iron offset stays one through a recording (:func:`offset_check`).

    Attributes
    ----------
    keep : ndarray of bool, shape (K,)
        Rows of the segment kept (every row when the offset does not change).
    segments : list of OffsetSegment
        The segments of one offset, in time order (:func:`magbench.core.offsets.
        offset_segments`), with the offsets of the last round's calibration (field strength
        1).
    spans : list of (float, float)
        Each segment's first and last time, s.
    chosen : int
        Index of the kept segment.
    """

    keep: np.ndarray
    segments: list[OffsetSegment]
    spans: list[tuple[float, float]]
    chosen: int

    @property
    def changed(self) -> bool:
        """More than one segment: the offset changed (or the field jumped at rest)."""
        return len(self.segments) > 1

    @property
    def kept_share(self) -> float:
        """The share of the rows in the kept segment."""
        return float(self.keep.mean())

    def warning(self) -> str:
        """The gate's reason when the offset changes (empty when it does not): the
        calibration holds for the kept segment only."""
        if not self.changed:
            return ""
        lo, hi = self.spans[self.chosen]
        return (f"the hard-iron offset changed within the recording: calibrated on t = "
                f"{lo:.1f}-{hi:.1f} s only ({100 * self.kept_share:.0f} % of the rows); "
                + ("check that part matches the vehicle as flown" if self.kept_share >= 0.5
                   else "most of the recording is in another state: record again with the "
                        "vehicle as flown"))

    def line(self) -> str:
        """One line for the printed report (empty when the offset does not change)."""
        if not self.changed:
            return ""
        lo, hi = self.spans[self.chosen]
        cuts = ", ".join(f"{b:.1f} s" for (_, b) in self.spans[:-1])
        return (f"offset: the hard-iron offset changes within the recording (after {cuts}); "
                f"fitted on t = {lo:.1f}-{hi:.1f} s ({int(self.keep.sum())} rows), the "
                f"segment that turns most; one calibration cannot fit the other segments")


def offset_check(rec: Recording, *, tol: float = 0.1, method: str = "magical",
                 rounds: int = 3, max_fit_rows: int = 2000,
                 window_s: float = 2.0) -> OffsetCheck | None:
    """Find where the hard-iron offset changes within a recording and the rows of one offset.

    A calibration fitted on the kept rows (all of them at first) gives the sensor-frame
    field; each window's extra offset (:func:`magbench.core.offsets.window_offsets`, with the
    reference attitude or, without one, the integrated gyro) cuts the recording into
    segments of one offset, and the segment that turns most is kept; the calibration is
    refitted on it and the recording cut again until the kept rows stay the same (a fit over
    two offsets is a compromise that fits neither, so the first cut can be too fine).

    Parameters
    ----------
    rec : Recording
        In time order, with times and a gyro or attitude columns (lag removed).
    tol : float
        Largest offset change within a segment, as a share of the field strength.
    method : str
        The calibration method of each round.
    rounds : int
        Largest number of fit-and-cut rounds.
    max_fit_rows : int
        Each round fits on at most about this many rows (an even stride).
    window_s : float
        Window length of the offsets, s.

    Returns
    -------
    OffsetCheck or None
        None without times and a rate (gyro, or an attitude that turns through at least
        :data:`MIN_ATTITUDE_SPAN_DEG`).
    """
    if rec.t is None:
        return None
    attitude = attitude_view(rec)            # rows normalised as read: no (K, 4) copy
    if attitude is not None and attitude_turn_deg(attitude) >= MIN_ATTITUDE_SPAN_DEG:
        orientation = MatrixView(attitude)         # matrices made a window at a time
    elif rec.gyro is not None:
        orientation = gyro_orientation(rec.t, rec.gyro)
    else:
        return None
    keep = np.ones(rec.K, dtype=bool)
    for _ in range(rounds):
        rows = np.flatnonzero(keep)
        rows = rows[::max(1, rows.size // max_fit_rows)]
        cal = calibrate(rec.y[rows], method).safe()
        # made a chunk of rows at a time (no (K, 3) temporary), then scaled in place
        field = affine_rows(rec.y, safe_gauge(cal.T, cal.h).A, cal.h, geometry.BLOCK_ROWS)
        field /= float(np.median(np.linalg.norm(field[rows], axis=1)))
        windows = window_offsets(rec.t, field, orientation, window_s=window_s)
        segments = offset_segments(windows, tol)
        new, best = consistent_rows(windows, segments, rec.K)
        if np.array_equal(new, keep):
            break
        keep = new
    spans = [(float(rec.t[windows.start[s.first]]),
              float(rec.t[min(windows.stop[s.last], rec.K) - 1])) for s in segments]
    return OffsetCheck(keep, segments, spans, segments.index(best))
