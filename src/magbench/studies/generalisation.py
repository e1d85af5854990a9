"""Generalisation on real recordings: fit on one part, score on the part that was not recorded.

A user calibrates on what they recorded and flies on everything else: other orientations,
later minutes. This study (``python -m magbench sweep=generalisation``) asks, for each recording
of ``data_dir`` and each *protocol* (:data:`PROTOCOLS`), how a fit made on one part does on the
other part, for every fixed method, for ``calibrate``'s automatic choice (its own decision,
:func:`magbench.pipeline.decision.decide`: a FAIL or no choice leaves the user the raw data) and
for the peers (navlib, magcal) when the optional ``peers`` extra is installed.

Protocols (:func:`split`):

* ``blocks``: ten time blocks, the even ones fitted, the odd ones scored;
* ``band_x``, ``band_y``, ``band_z``: the samples whose field direction (from the sphere-fit
  centre of the whole recording) lies within +-15 deg of the plane normal to that sensor axis
  are fitted, every other sample is scored: extrapolation to directions never recorded;
* ``half``: the first half fitted, the second scored (a state change shows here);
* ``first15``: the first 15 % fitted, the rest scored (a short recording);
* ``spikes``: as ``blocks``, with 5 % of the fitted samples hit by spikes (seeded);
* ``still_first``: as ``blocks``, the fitted part preceded by as many still samples (the first
  sample held, with the recording's own sample-to-sample noise): a first half at rest.

Scores on the held-out part (:func:`scores`): the field-magnitude spread ``100 std|m| /
mean|m|`` (%) of the corrected samples, and, where the recording carries a reference attitude,
the heading error (RMS, deg, BROAD's definition) against the recording's world field
(:func:`world_reference`: the field the attitude and the raw samples of the whole recording
imply), and beside it the world-frame direction spread about its own mean direction, which a
sensor that barely turns keeps small whatever it points at. The raw data's scores are the "no
correction" line; their magnitude spread is a share of the *field*, ``100 std|y| / r`` with
``r`` the robust radius of the whole recording (:func:`magbench.core.robust.screen`), not of
their mean norm: raw samples whose
offset exceeds the field have a mean norm of about the offset, so any spread looks small beside
it (a phone with a 409 uT hard iron in a 41 uT field: 5 % "raw" while the raw field points
60-96 deg astray). ``raw_mean_spread_pct`` keeps the mean-norm figure. :func:`case_table` and
:func:`protocol_table` turn the rows into what the report says: regret of the automatic choice
against the best fixed method in hindsight, wins, ties and losses against every fixed method
and peer, corrections written worse than raw (and, beside, worse than raw by its mean-norm
spread), FAILs where a fixed method would have helped, and, with an attitude, losses by
heading against the best fixed method (by more than max(1 deg, 10 %): :func:`tolerance_deg`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from magbench.core.direction import (
    attitude_field,
    direction_spread,
    heading_errors,
    rms,
    world_field,
)
from magbench.core.files import write_csv_atomic
from magbench.core.geometry import coverage, sphere_fit, unit_rows
from magbench.core.model import Calibration
from magbench.core.robust import screen
from magbench.core.seeding import rng
from magbench.engine.sweep import Study, settings_hash
from magbench.engine.trial import run_method
from magbench.pipeline.auto import candidate_rounds
from magbench.pipeline.bootstrap import bootstrap_check
from magbench.pipeline.choice import passed_over
from magbench.pipeline.decision import Decision, decide, written_correction
from magbench.pipeline.fitting import DEFAULT_MAX_SAMPLES, applicability, fit_recording, is_usable
from magbench.pipeline.holdout import estimate
from magbench.sources.recordings import Recording, load_recording
from magbench.studies.peers import PEER_FITS, PEER_NEEDS_FIELD, available_peers, fit_peer

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["AUTO", "INTERVAL_COLUMNS", "MIN_PART", "PROTOCOLS", "ROW_COLUMNS",
           "GeneralisationStudy", "case_table", "fixed_methods", "interval_rows",
           "protocol_table", "scores", "split", "tolerance", "tolerance_deg"]

#: Every protocol, in report order (module notes).
PROTOCOLS = ("blocks", "band_x", "band_y", "band_z", "half", "first15", "spikes",
             "still_first")
#: The entrant name of ``calibrate``'s automatic choice.
AUTO = "calibrate"
#: Fewest samples in a fitted or a scored part; a protocol that leaves fewer is skipped.
MIN_PART = 60
#: Half-width of a band (deg) about the plane normal to a sensor axis.
BAND_DEG = 15.0
#: Share of the fitted samples hit by spikes.
SPIKE_SHARE = 0.05
#: Recordings of at least this long (s) enter the interval check (goal: halves agree).
INTERVAL_MIN_S = 120.0

ROW_COLUMNS = ["dataset", "protocol", "algorithm", "kind", "K_fit", "K_test", "status", "ok",
               "written", "degenerate", "method", "spread_pct", "raw_spread_pct",
               "raw_mean_spread_pct", "direction_deg", "raw_direction_deg", "heading_deg",
               "raw_heading_deg", "field_ratio", "oracle_method", "oracle_pct",
               "oracle_heading_deg", "passed_over", "error"]
INTERVAL_COLUMNS = ["dataset", "axis", "method_first", "method_second", "b_first", "b_second",
                    "half_width_first", "half_width_second", "source_first",
                    "source_second", "agree"]


def tolerance(best: float | np.ndarray) -> float | np.ndarray:
    """How much worse than ``best`` still ties: max(0.25 points, 5 %) (elementwise for an
    array)."""
    return np.maximum(0.25, 0.05 * best)


def tolerance_deg(best: float) -> float:
    """How much worse than ``best`` (deg) a direction spread still ties: max(1 deg, 10 %)."""
    return max(1.0, 0.1 * best)


def _candidate_pool() -> list[str]:
    """Every method ``calibrate``'s automatic choice as shipped may fit on some recording
    (with or without a gyroscope, either round): what its rows depend on. A user's plugin is
    a fixed entrant, not one of its candidates: the study measures the choice users get."""
    pool: list[str] = []
    for gyro in (False, True):
        for names in candidate_rounds(gyro, "auto", shipped=True):
            pool += [m for m in names if m not in pool]
    return pool


def fixed_methods() -> list[str]:
    """The magnetometer-only methods ``calibrate`` may choose (its ``candidates=all`` without a
    gyroscope): each is a fixed entrant."""
    return candidate_rounds(False, "all")[0]


# --- protocols -----------------------------------------------------------------------------

def _blocks(K: int, n: int = 10) -> tuple[np.ndarray, np.ndarray]:
    blocks = np.array_split(np.arange(K), n)
    return np.concatenate(blocks[0::2]), np.concatenate(blocks[1::2])


def _spiked(fit: Recording, radius: float, gen: np.random.Generator) -> Recording:
    """``fit`` with :data:`SPIKE_SHARE` of its samples moved by 0.5-2 radii in a random
    direction (a bumped sensor, a motor switched on)."""
    y = fit.y.copy()
    hit = gen.choice(fit.K, size=max(1, round(SPIKE_SHARE * fit.K)), replace=False)
    y[hit] += unit_rows(gen.standard_normal((hit.size, 3))) * \
        (radius * gen.uniform(0.5, 2.0, hit.size))[:, None]
    return replace(fit, y=y)


def _still_then(fit: Recording, gen: np.random.Generator) -> Recording:
    """As many still samples as ``fit`` has, then ``fit``: the first sample held with the
    recording's own noise (robust spread of the second differences), times before the first,
    inertial columns held at their first row."""
    n = fit.K
    # Second differences cancel a smooth turn: var(d2 y) = 6 sigma^2 for white noise.
    d2 = np.diff(fit.y, n=2, axis=0)
    noise = 1.4826 * np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0) / np.sqrt(6)
    still = fit.y[0] + gen.standard_normal((n, 3)) * noise
    t = None
    if fit.t is not None:
        dt = float(np.median(np.diff(fit.t))) if fit.K > 1 else 0.01
        t = np.concatenate([fit.t[0] - dt * np.arange(n, 0, -1), fit.t])
    gyro = None if fit.gyro is None else np.concatenate([np.zeros((n, 3)), fit.gyro])
    extra = None if fit.extra is None else {
        k: np.concatenate([np.repeat(v[:1], n, axis=0), v]) for k, v in fit.extra.items()}
    return replace(fit, y=np.concatenate([still, fit.y]), t=t, gyro=gyro, extra=extra)


def split(rec: Recording, protocol: str, seed: int = 0) -> tuple[Recording, Recording] | str:
    """The fitted and the scored part of ``rec`` under ``protocol`` (module notes), or why the
    protocol does not apply (a part of fewer than :data:`MIN_PART` samples)."""
    K = rec.K
    gen = rng(seed, "generalisation", rec.name, protocol)
    centre, radius = sphere_fit(rec.y)
    if protocol in ("blocks", "spikes", "still_first"):
        fit_idx, test_idx = _blocks(K)
    elif protocol.startswith("band_"):
        axis = "xyz".index(protocol[-1])
        u = unit_rows(rec.y - centre)
        inside = np.abs(np.degrees(np.arcsin(np.clip(u[:, axis], -1, 1)))) <= BAND_DEG
        fit_idx, test_idx = np.flatnonzero(inside), np.flatnonzero(~inside)
    elif protocol == "half":
        fit_idx, test_idx = np.arange(K // 2), np.arange(K // 2, K)
    elif protocol == "first15":
        n = round(0.15 * K)
        fit_idx, test_idx = np.arange(n), np.arange(n, K)
    else:
        raise ValueError(f"unknown protocol {protocol!r}; expected one of {PROTOCOLS}")
    if min(fit_idx.size, test_idx.size) < MIN_PART:
        return (f"skipped: the {protocol} protocol leaves {fit_idx.size} samples to fit and "
                f"{test_idx.size} to score ({MIN_PART} needed each)")
    fit, test = rec.rows(fit_idx), rec.rows(test_idx)
    if protocol == "spikes":
        fit = _spiked(fit, radius, gen)
    elif protocol == "still_first":
        fit = _still_then(fit, gen)
    return fit, test


# --- scores --------------------------------------------------------------------------------

def _attitude(rec: Recording) -> np.ndarray | None:
    """The reference attitude (K, 4), NaN rows where it is missing; None without one."""
    names = ("qw", "qx", "qy", "qz")
    if rec.extra is None or not all(n in rec.extra for n in names):
        return None
    return np.column_stack([rec.extra[n] for n in names])


def scores(test: Recording, A: np.ndarray | None = None, b: np.ndarray | None = None,
           field: float | None = None, reference: np.ndarray | None = None
           ) -> tuple[float, float, float]:
    """Held-out field-magnitude spread (%), world-frame direction spread (deg RMS about the
    mean direction) and heading error (deg RMS, BROAD's definition, against ``reference``,
    the recording's world field: :func:`~magbench.core.direction.attitude_field`) of
    ``test`` corrected by ``m = A (y - b)`` (raw without ``A``). The angles use the rows with
    an attitude: NaN without one, or when fewer than half the rows have it; the heading is
    NaN without ``reference``. The spread is a share of the mean norm, or of ``field`` when
    given (raw data: the field's strength in their units)."""
    m = test.y if A is None else (test.y - b) @ np.asarray(A).T
    norm = np.linalg.norm(m, axis=1)
    spread = float(100 * norm.std() / (norm.mean() if field is None else field))
    q = _attitude(test)
    known = np.zeros(test.K, dtype=bool) if q is None else np.isfinite(q).all(axis=1)
    if known.sum() < max(MIN_PART, 0.5 * test.K):
        return spread, float("nan"), float("nan")
    world = world_field(m[known], q[known])
    angles = np.degrees(direction_spread(world))
    heading = float("nan")
    if reference is not None:
        heading = rms(np.degrees(heading_errors(world, reference)))
    return spread, float(np.sqrt(np.mean(angles ** 2))), heading


def world_reference(rec: Recording) -> np.ndarray | None:
    """The recording's world field (:func:`~magbench.core.direction.attitude_field` of every
    row), against which every entrant's heading is scored; None without an attitude."""
    q = _attitude(rec)
    return None if q is None else attitude_field(rec.y, q)


def _degenerate(test: Recording, A: np.ndarray, b: np.ndarray, sphere_coverage: float) -> bool:
    """The degenerate answer (``h`` far away, every corrected sample near one point, which
    makes any spread small): corrected directions cover less than half of what the sphere
    fit's cover (:func:`magbench.pipeline.fitting.is_usable`)."""
    return not is_usable(coverage((test.y - b) @ np.asarray(A).T), sphere_coverage)


def _row(rec: Recording, protocol: str, entrant: str, kind: str, fit: Recording,
         test: Recording, raw: tuple[float, ...], *, A=None, b=None, status: str = "",
         written: bool = False, method: str = "", radius: float = float("nan"),
         sphere_coverage: float = float("nan"), error: str = "",
         reference: np.ndarray | None = None) -> dict:
    spread, direction, heading = (scores(test, A, b, reference=reference) if A is not None
                                  else (float("nan"),) * 3)
    ratio = float("nan")
    degenerate = False
    if A is not None:
        degenerate = _degenerate(test, A, b, sphere_coverage)
        # The fitted field strength over the data's own radius: a fit whose scale is far off
        # is a wrong unit or a collapsed fit, whatever its shape.
        ratio = float(1.0 / np.cbrt(abs(np.linalg.det(A))) / radius)
    return {"dataset": rec.name, "protocol": protocol, "algorithm": entrant, "kind": kind,
            "K_fit": fit.K, "K_test": test.K, "status": status,
            "ok": status not in ("failed", "ERROR"), "written": bool(written),
            "degenerate": degenerate, "method": method, "spread_pct": spread,
            "raw_spread_pct": raw[0], "raw_mean_spread_pct": raw[2],
            "direction_deg": direction, "raw_direction_deg": raw[1],
            "heading_deg": heading, "raw_heading_deg": raw[3], "field_ratio": ratio,
            "oracle_method": "", "oracle_pct": float("nan"),
            "oracle_heading_deg": float("nan"), "passed_over": "", "error": error}


def _fixed_rows(rec, protocol, fit, test, raw, names, options, seed, timeout, radius,
                sphere_coverage, reference=None):
    thin = fit.thinned(DEFAULT_MAX_SAMPLES)
    rows, times = [], []
    for name in names:
        reason = applicability(name, thin)
        if reason:
            rows.append(_row(rec, protocol, name, "fixed", fit, test, raw, error=reason))
            times.append(float("nan"))
            continue
        out = run_method(name, lambda o, n=name: fit_recording(thin, n, "centre", o),
                         options=dict(options.get(name) or {}), seed=seed,
                         stream=("generalisation", rec.name, protocol),
                         call_timeout_s=timeout)
        A = b = None
        error = out.error
        if out.T is not None and not error:
            try:
                A, b = Calibration(out.T, out.h).correction()
            except Exception as exc:    # a singular fit is a row with its reason
                error = f"{type(exc).__name__}: {exc}"
        rows.append(_row(rec, protocol, name, "fixed", fit, test, raw, A=A, b=b,
                         status="ok" if A is not None else "failed", written=A is not None,
                         method=name, radius=radius, sphere_coverage=sphere_coverage,
                         error=error or "", reference=reference))
        times.append(out.time_s)
    return rows, times


def _peers() -> list[str]:
    """The installed magnetometer-only peers a user runs on a recording as it is (not those
    that need the field's strength given, :data:`~magbench.studies.peers.PEER_NEEDS_FIELD`)."""
    return [n for n in available_peers() if n not in PEER_NEEDS_FIELD]


def _peer_version(name: str) -> str:
    """The installed version of the package peer ``name`` comes from (what its rows depend
    on besides its adapter, whose code is the study's)."""
    from importlib.metadata import PackageNotFoundError, version

    package = PEER_FITS[name][0].split(".")[0]
    try:
        return f"{package} {version(package)}"
    except PackageNotFoundError:
        return f"{package} (version unknown)"


def _peer_rows(rec, protocol, fit, test, raw, radius, sphere_coverage, names=None, reference=None):
    thin = fit.thinned(DEFAULT_MAX_SAMPLES)
    rows, times = [], []
    for name in _peers() if names is None else names:
        start = time.perf_counter()
        try:
            with warnings.catch_warnings():     # a peer's own warnings are not the user's
                warnings.simplefilter("ignore")
                A, b = Calibration(*fit_peer(name, thin.y)).correction()
            rows.append(_row(rec, protocol, name, "peer", fit, test, raw, A=A, b=b,
                             status="ok", written=True, method=name, radius=radius,
                             sphere_coverage=sphere_coverage, reference=reference))
        except Exception as exc:        # a peer's failure is a row, as a method's
            rows.append(_row(rec, protocol, name, "peer", fit, test, raw, status="failed",
                             error=f"{type(exc).__name__}: {exc}"[:200]))
        times.append(time.perf_counter() - start)
    return rows, times


def _recording_key(rec: Recording) -> str:
    """A digest of every field of ``rec`` (arrays by their bytes): two parts with the same
    key are the same input to :func:`~magbench.pipeline.decision.decide`."""
    digest = hashlib.sha256()

    def add(value: object) -> None:
        if isinstance(value, np.ndarray):
            digest.update(f"{value.dtype}{value.shape}".encode())
            digest.update(np.ascontiguousarray(value).tobytes())
        elif isinstance(value, Mapping):
            for key in sorted(value):
                digest.update(f"<{key}>".encode())
                add(value[key])
        else:
            digest.update(repr(value).encode())

    for f in dataclasses.fields(rec):
        digest.update(f"|{f.name}=".encode())
        add(getattr(rec, f.name))
    return digest.hexdigest()


def _decide(part: Recording, options: dict | None, seed: int, timeout: float | None,
            memo: dict[str, Decision] | None = None) -> Decision:
    """``calibrate``'s decision on ``part`` as the command makes it; with ``memo``, a part
    decided before in the same unit (the ``half`` protocol's fitted part is the interval
    check's first half) is not decided again: :func:`decide` is deterministic, so the
    decision is the same."""
    key = _recording_key(part) if memo is not None else ""
    if memo is not None and key in memo:
        return memo[key]
    first, second = candidate_rounds(part.has_gyro, "auto", shipped=True)
    decision = decide(part, first, second_round=second, options=options, seed=seed,
                      call_timeout_s=timeout, max_samples=DEFAULT_MAX_SAMPLES)
    if memo is not None:
        memo[key] = decision
    return decision


def _auto_row(rec, protocol, fit, test, raw, options, seed, timeout, radius, sphere_coverage,
              reference=None, memo=None):
    start = time.perf_counter()
    try:
        decision = _decide(fit, options, seed, timeout, memo)
    except Exception as exc:            # the command would exit 2 with one line
        return (_row(rec, protocol, AUTO, "auto", fit, test, raw, status="ERROR",
                     error=f"{type(exc).__name__}: {exc}"[:300]),
                time.perf_counter() - start)
    cal = written_correction(decision)
    chosen = decision.result.chosen
    method = "" if chosen is None else str(chosen["algorithm"])
    reasons = (decision.result.fitness or {}).get("reasons") or []
    A = b = None
    if cal is not None:
        A, b = cal.correction()
    row = _row(rec, protocol, AUTO, "auto", fit, test, raw, A=A, b=b, status=decision.status,
               written=decision.written, method=method, radius=radius,
               sphere_coverage=sphere_coverage,
               error="; ".join(str(r) for r in reasons)[:300], reference=reference)
    if A is None and chosen is not None:
        # What the user is left with is the raw data; the ratio is still worth keeping.
        T, _ = estimate(chosen)
        row["field_ratio"] = float(np.cbrt(abs(np.linalg.det(T))) / radius)
    row.update(_oracle(decision.result.ranked, test, sphere_coverage, reference))
    # The fits the choice passed over as possibly worse than no correction off the data.
    row["passed_over"] = ";".join(passed_over(decision.result.ranked))
    return row, time.perf_counter() - start


def _oracle(ranked: Sequence[Mapping], test: Recording, sphere_coverage: float,
            reference: np.ndarray | None) -> dict:
    """The best held-out scores among the candidates calibrate judged eligible, as if it had
    chosen in hindsight and written whatever the gate said: the headroom of its ranking.
    ``oracle_method`` is the best by magnitude; the heading's best may be another
    candidate. A degenerate answer is never the best."""
    best = {"oracle_method": "", "oracle_pct": float("nan"),
            "oracle_heading_deg": float("nan")}
    for r in ranked:
        if not r.get("eligible"):
            continue
        try:
            A, b = Calibration(*estimate(r)).correction()
        except Exception:               # a singular fit has no score
            continue
        if _degenerate(test, A, b, sphere_coverage):
            continue
        spread, _, heading = scores(test, A, b, reference=reference)
        if not spread >= best["oracle_pct"]:
            best["oracle_method"], best["oracle_pct"] = str(r["algorithm"]), spread
        if not heading >= best["oracle_heading_deg"]:
            best["oracle_heading_deg"] = heading
    return best


def evaluate_protocol(rec: Recording, protocol: str, *, fixed: Sequence[str],
                      peers: bool | Sequence[str] = True, options: dict | None = None,
                      seed: int = 0, call_timeout_s: float | None = None,
                      field: float | None = None, auto: bool = True,
                      reference: np.ndarray | None = None,
                      memo: dict[str, Decision] | None = None
                      ) -> tuple[list[dict], list[dict]]:
    """Rows (and their times) of every entrant on ``rec`` under ``protocol``: the automatic
    choice (``auto``), each of ``fixed``, each installed peer (``peers``: True, or the peers
    to run); one skipped row when the protocol does not apply. ``field``: the recording's
    field strength, the raw spread's scale (its robust radius by default); ``reference``:
    its world field, the headings' truth (:func:`~magbench.core.direction.attitude_field`
    of the whole recording by default). A caller running every protocol passes both once.
    ``memo``: decisions already made on a part of ``rec`` (:func:`_decide`), and where this
    one's goes."""
    options = options or {}
    parts = split(rec, protocol, seed)
    if isinstance(parts, str):
        if not auto:
            return [], []
        empty = replace(rec, y=np.zeros((0, 3)), t=None, gyro=None, extra=None)
        row = _row(rec, protocol, AUTO, "auto", empty, empty, (np.nan,) * 4,
                   status="SKIPPED", error=parts)
        return [row], [{"dataset": rec.name, "protocol": protocol, "algorithm": AUTO,
                        "time_s": 0.0}]
    fit, test = parts
    field = screen(rec.y).radius if field is None else field
    reference = world_reference(rec) if reference is None else reference
    mean_spread, direction, heading = scores(test, reference=reference)
    raw = (scores(test, field=field)[0], direction, mean_spread, heading)
    centre, radius = sphere_fit(fit.y)
    # What the fit part's sphere fit makes of the scored samples, every entrant's yardstick.
    sphere_coverage = coverage(test.y - centre)
    rows, times = [], []
    if auto:
        row, t = _auto_row(rec, protocol, fit, test, raw, options, seed, call_timeout_s,
                           radius, sphere_coverage, reference, memo)
        rows.append(row)
        times.append(t)
    r, t = _fixed_rows(rec, protocol, fit, test, raw, fixed, options, seed, call_timeout_s,
                       radius, sphere_coverage, reference)
    rows += r
    times += t
    if peers:
        r, t = _peer_rows(rec, protocol, fit, test, raw, radius, sphere_coverage,
                          None if peers is True else list(peers), reference)
        rows += r
        times += t
    return rows, [{"dataset": rec.name, "protocol": protocol, "algorithm": r["algorithm"],
                   "time_s": s} for r, s in zip(rows, times, strict=True)]


# --- honest intervals ----------------------------------------------------------------------

def interval_rows(rec: Recording, *, options: dict | None = None, seed: int = 0,
                  bootstrap: int = 50, call_timeout_s: float | None = None,
                  memo: dict[str, Decision] | None = None) -> list[dict]:
    """The offsets ``calibrate`` writes from the first and from the second half of ``rec``,
    with their printed 95 % half-widths (the wider of model-based and block bootstrap), per
    axis; ``agree`` when the difference is within the two half-widths combined in quadrature
    (the 95 % interval of the difference of two independent estimates). Empty for recordings
    shorter than :data:`INTERVAL_MIN_S` or when a half writes nothing. ``memo``: as
    :func:`evaluate_protocol`'s (the first half is the ``half`` protocol's fitted part)."""
    if rec.t is None or rec.t[-1] - rec.t[0] < INTERVAL_MIN_S:
        return []
    halves = []
    for part in (rec.rows(np.arange(rec.K // 2)), rec.rows(np.arange(rec.K // 2, rec.K))):
        d = _decide(part, options, seed, call_timeout_s, memo)
        if not d.written:
            return []
        d.result.bootstrap = bootstrap_check(d.result, bootstrap, options=options or {},
                                             seed=seed)
        iv, bs = d.result.intervals, d.result.bootstrap
        width = np.array(bs["wider_h"]) if bs else np.asarray(iv.h_half)
        source = bs["source_h"] if bs else "model-based"
        halves.append((str(d.result.chosen["algorithm"]), estimate(d.result.chosen)[1], width,
                       source))
    (m1, b1, w1, s1), (m2, b2, w2, s2) = halves
    return [{"dataset": rec.name, "axis": "xyz"[i], "method_first": m1, "method_second": m2,
             "b_first": b1[i], "b_second": b2[i], "half_width_first": w1[i],
             "half_width_second": w2[i], "source_first": s1, "source_second": s2,
             "agree": bool(abs(b1[i] - b2[i]) <= np.hypot(w1[i], w2[i]))} for i in range(3)]


# --- the study -----------------------------------------------------------------------------

@dataclass(frozen=True)
class GeneralisationStudy(Study):
    """One work unit per recording: every protocol, then the interval check.

    Rows are cached per entrant (:meth:`entrants`): a unit's rows come entrant by entrant
    (calibrate's choice on every protocol, then each fixed method, then each peer), the
    interval check is calibrate's. Calibrate's key is its whole candidate pool as shipped
    (every method of magbench's it may fit on a recording, with its options and code), so a
    candidate's options or code changed recompute its rows, while a plugin is a fixed entrant
    only; a peer's key is its package's version. ``only`` (None: every entrant) is what a
    cached run computes.
    """

    root: str
    datasets: Sequence[str]
    protocols: Sequence[str] = PROTOCOLS
    algorithms: Sequence[str] = ()
    peers: bool = True
    bootstrap: int = 50
    options: dict | None = None
    seed: int = 0
    call_timeout_s: float | None = None
    plugins: Sequence[str] = ()
    name: str = "generalisation"
    only: tuple[str, ...] | None = None

    tables: ClassVar[dict] = {
        "trials": ("generalisation_trials.csv", ROW_COLUMNS),
        "times": ("generalisation_trials_times.csv",
                  ["dataset", "protocol", "algorithm", "time_s"]),
        "intervals": ("generalisation_intervals.csv", INTERVAL_COLUMNS)}
    method_column: ClassVar[str] = "algorithm"
    method_fields: ClassVar[tuple[str, ...]] = ("algorithms", "options", "plugins", "only")
    table_owner: ClassVar[dict] = {"intervals": AUTO}
    ragged: ClassVar[bool] = True       # a skipped protocol has calibrate's row only

    def entrants(self) -> list[str]:
        every = [AUTO, *self.algorithms, *(_peers() if self.peers else [])]
        return every if self.only is None else [e for e in every if e in self.only]

    def with_methods(self, names: Sequence[str]) -> GeneralisationStudy:
        # Every option is kept: calibrate's choice fits candidates that are not entrants.
        return replace(self, only=tuple(names))

    def method_key(self, name: str) -> dict[str, str]:
        if name == AUTO:
            pool = _candidate_pool()
            keys = {m: Study.method_key(self, m) for m in pool}
            return {"options": settings_hash({m: k["options"] for m, k in keys.items()}),
                    "code": f"candidates {','.join(pool)}:"
                            f"{settings_hash({m: k['code'] for m, k in keys.items()})}"}
        if name in PEER_FITS:
            return {"options": "", "code": _peer_version(name)}
        return super().method_key(name)

    def units(self) -> list[str]:
        return list(self.datasets)

    def estimated_rows(self, units: Sequence) -> int:
        return len(units) * len(self.protocols) * (2 + len(self.algorithms))

    def describe(self) -> dict:
        out = super().describe()
        out["peers_installed"] = _peers() if self.peers else []
        return out

    def run_unit(self, name: str) -> dict[str, list[dict]]:
        rec = load_recording(self.root, name, check=False)
        entrants = self.entrants()
        per: dict[str, tuple[list, list]] = {e: ([], []) for e in entrants}
        field, reference = screen(rec.y).radius, world_reference(rec)
        # calibrate's decisions on parts of this recording, made once each (:func:`_decide`).
        memo: dict[str, Decision] = {}
        for protocol in self.protocols:
            r, t = evaluate_protocol(rec, protocol,
                                     fixed=[a for a in self.algorithms if a in per],
                                     peers=[p for p in entrants if p in PEER_FITS],
                                     options=self.options, seed=self.seed,
                                     call_timeout_s=self.call_timeout_s, field=field,
                                     auto=AUTO in per, reference=reference, memo=memo)
            for row, time_row in zip(r, t, strict=True):
                per[row["algorithm"]][0].append(row)
                per[row["algorithm"]][1].append(time_row)
        # Entrant by entrant (the engine caches each one's rows), protocols in order within.
        rows = [row for e in entrants for row in per[e][0]]
        times = [row for e in entrants for row in per[e][1]]
        intervals = interval_rows(rec, options=self.options, seed=self.seed,
                                  bootstrap=self.bootstrap,
                                  call_timeout_s=self.call_timeout_s, memo=memo) \
            if self.bootstrap and AUTO in per else []
        return {"trials": rows, "times": times, "intervals": intervals}

    def summarize(self, out_dir: Path | str) -> None:
        """``generalisation_cases.csv`` (one row per recording and protocol) and
        ``generalisation_summary.csv`` (one per protocol, and ``all``)."""
        import pandas as pd

        out_dir = Path(out_dir)
        trials = pd.read_csv(out_dir / "generalisation_trials.csv", keep_default_na=False,
                             na_values=[""])
        cases = case_table(trials)
        write_csv_atomic(cases, out_dir / "generalisation_cases.csv")
        write_csv_atomic(protocol_table(cases), out_dir / "generalisation_summary.csv")


# --- summaries -----------------------------------------------------------------------------

def _user_score(row: Mapping, raw: str = "raw_spread_pct") -> float:
    """What the user is left with: the correction if written (NaN if it is the degenerate
    answer, whose small spread means nothing), else the raw data (column ``raw``)."""
    if not bool(row["written"]):
        return float(row[raw])
    return np.nan if bool(row["degenerate"]) else float(row["spread_pct"])


def _beyond_best_direction(value: float, fixed: pd.DataFrame,
                           column: str = "direction_deg") -> bool:
    """Whether an angle ``value`` (a world-frame direction spread, or a heading error with
    ``column="heading_deg"``) is worse than the best fixed fit's by more than
    :func:`tolerance_deg` (NaN is worse; False when no fixed fit has one)."""
    best = fixed[column].to_numpy(float)
    best = best[np.isfinite(best)]
    return bool(best.size and not value <= best.min() + tolerance_deg(best.min()))


def case_table(trials: pd.DataFrame) -> pd.DataFrame:
    """One row per (dataset, protocol) that was run: the automatic choice's score (raw when
    nothing was written), the best fixed method in hindsight, the regret, and whether it is a
    loss (worse than the best by more than :func:`tolerance`), a harmful write (written and
    worse than raw) or a needless FAIL (nothing written where the best fixed fit beats raw by
    more than the tolerance). ``harmful_mean_norm`` judges the raw data by their mean-norm
    spread instead (the issue's first definition, which a large offset deflates);
    ``loss_direction`` compares world-frame direction spreads where an attitude exists, and
    ``loss_heading`` heading errors against the recording's world field (the compass's own
    error: a spread about its own mean rewards raw data that barely turn, whatever they
    point at); ``loss_compass`` is the score the choice serves: by heading where the
    recording has an attitude, by magnitude elsewhere, and so are ``harmful_compass`` and
    ``needless_fail_compass``. ``loss_peers``: worse by magnitude
    than the best installed peer (navlib, magcal) by more than the tolerance, the comparison
    a user of those libraries makes (False without peers). ``loss_oracle`` and
    ``loss_compass_oracle``: the same losses for the best of calibrate's eligible
    candidates in hindsight (:func:`_oracle`), so that what a better ranking could win is
    told apart from what the candidates and the gate leave. ``tied``: how many fixed
    methods are within the tolerance of the best (1: only the best itself);
    ``passed_over``: the fits calibrate's choice passed over as possibly worse than no
    correction off the recorded directions (``;``-separated,
    :func:`~magbench.pipeline.choice.beyond_raw`); and
    ``recording_best`` / ``loss_recording_best``: :func:`_with_recording_best`."""
    import pandas as pd

    out = []
    for (dataset, protocol), g in trials.groupby(["dataset", "protocol"], sort=False):
        auto = g[g["kind"] == "auto"].iloc[0]
        if auto["status"] == "SKIPPED":
            continue
        fixed = g[(g["kind"] == "fixed") & g["written"].astype(bool)
                  & ~g["degenerate"].astype(bool)]
        best = fixed.loc[fixed["spread_pct"].idxmin()] if len(fixed) else None
        score = _user_score(auto)
        raw = float(auto["raw_spread_pct"])
        best_score = float(best["spread_pct"]) if best is not None else np.nan
        tol = tolerance(best_score) if best is not None else np.nan
        written = bool(auto["written"])
        row = {"dataset": dataset, "protocol": protocol, "status": auto["status"],
               "method": auto["method"], "written": written, "auto_pct": score,
               "raw_pct": raw, "best_fixed": best["algorithm"] if best is not None else "",
               "best_fixed_pct": best_score, "regret": score - best_score,
               "loss": bool(not score <= best_score + tol) if best is not None else False,
               "harmful": bool(written and not score <= raw),
               "harmful_mean_norm": bool(written and not score <= float(
                   auto["raw_mean_spread_pct"])),
               "has_attitude": bool(np.isfinite(float(auto["raw_direction_deg"]))),
               "needless_fail": bool(not written and best is not None
                                     and raw > best_score + tol),
               "auto_direction_deg": float(auto["direction_deg"]) if written else
               float(auto["raw_direction_deg"]),
               "raw_direction_deg": float(auto["raw_direction_deg"]),
               "auto_heading_deg": float(auto["heading_deg"]) if written else
               float(auto["raw_heading_deg"]),
               "raw_heading_deg": float(auto["raw_heading_deg"]),
               "best_fixed_heading_deg": float(np.nanmin(fixed["heading_deg"].to_numpy(float)))
               if np.isfinite(fixed["heading_deg"].to_numpy(float)).any() else np.nan}
        attitude = row["has_attitude"]
        row["loss_direction"] = attitude and _beyond_best_direction(
            row["auto_direction_deg"], fixed)
        heading = bool(np.isfinite(row["raw_heading_deg"]))
        user, raw_heading = row["auto_heading_deg"], row["raw_heading_deg"]
        row["loss_heading"] = heading and _beyond_best_direction(user, fixed, "heading_deg")
        row["loss_compass"] = row["loss_heading"] if heading else row["loss"]
        row["harmful_compass"] = (bool(written and not user <= raw_heading)
                                  if heading else row["harmful"])
        row["needless_fail_compass"] = (
            not written and _beyond_best_direction(raw_heading, fixed, "heading_deg")
            if heading else row["needless_fail"])
        peers = g[(g["kind"] == "peer") & g["written"].astype(bool)
                  & ~g["degenerate"].astype(bool)]["spread_pct"].to_numpy(float)
        peers = peers[np.isfinite(peers)]
        row["loss_peers"] = bool(peers.size and not score <= peers.min() +
                                 tolerance(peers.min()))
        # The oracle leaves the raw data only where no candidate was eligible.
        oracle = float(auto.get("oracle_pct", np.nan))
        oracle = raw if np.isnan(oracle) else oracle
        oracle_heading = float(auto.get("oracle_heading_deg", np.nan))
        oracle_heading = raw_heading if np.isnan(oracle_heading) else oracle_heading
        row["oracle_pct"] = oracle
        row["loss_oracle"] = bool(best is not None and not oracle <= best_score + tol)
        row["loss_compass_oracle"] = (
            _beyond_best_direction(oracle_heading, fixed, "heading_deg") if heading
            else row["loss_oracle"])
        row["tied"] = int(np.sum(fixed["spread_pct"].to_numpy(float) <= best_score + tol))
        passed = auto.get("passed_over", "")
        row["passed_over"] = passed if isinstance(passed, str) else ""
        for _, r in g[g["kind"] != "auto"].iterrows():
            row[f"pct:{r['algorithm']}"] = _user_score(r) if r["status"] == "ok" else raw
        out.append(row)
    fixed_names = list(dict.fromkeys(trials.loc[trials["kind"] == "fixed", "algorithm"]))
    return _with_recording_best(pd.DataFrame(out), fixed_names)


def _with_recording_best(cases: pd.DataFrame, fixed: Sequence[str]) -> pd.DataFrame:
    """Add ``recording_best`` and ``loss_recording_best``: per recording, the one fixed method
    that loses least over all its protocols, chosen knowing every held-out score, and whether
    it loses each case. No choice made per recording can lose fewer cases: it bounds what
    any rule that does not see the held-out part can hope for."""
    cases = cases.copy()
    cases["recording_best"], cases["loss_recording_best"] = "", False
    columns = [f"pct:{name}" for name in fixed if f"pct:{name}" in cases.columns]
    if cases.empty or not columns:
        return cases
    best = cases["best_fixed_pct"].to_numpy(float)
    with np.errstate(invalid="ignore"):
        lost = ~(cases[columns].to_numpy(float) <= (best + tolerance(best))[:, None]) \
            & np.isfinite(best)[:, None]
    for _, index in cases.groupby("dataset", sort=False).groups.items():
        rows = cases.index.get_indexer(index)
        k = int(np.argmin(lost[rows].sum(axis=0)))
        cases.loc[index, "recording_best"] = columns[k].removeprefix("pct:")
        cases.loc[index, "loss_recording_best"] = lost[rows, k]
    return cases


def _wtl(auto: np.ndarray, other: np.ndarray) -> tuple[int, int, int]:
    """Wins, ties and losses; a degenerate answer (NaN) loses to any other."""
    auto = np.where(np.isnan(auto), np.inf, auto)
    other = np.where(np.isnan(other), np.inf, other)
    tol = tolerance(np.where(np.isfinite(other), other, 0.0))
    with np.errstate(invalid="ignore"):
        tie = (np.abs(auto - other) <= tol) | (np.isinf(auto) & np.isinf(other))
        return (int(np.sum((auto < other - tol) & ~tie)), int(np.sum(tie)),
                int(np.sum((auto > other + tol) & ~tie)))


def protocol_table(cases: pd.DataFrame) -> pd.DataFrame:
    """Per protocol (and ``all``): cases, median and worst regret, losses, harmful writes,
    needless FAILs, FAILs, the cases where the choice passed over a fit (``passed_over``),
    and wins/ties/losses against each fixed method and peer (``wtl:<entrant>`` as
    ``W/T/L``)."""
    import pandas as pd

    entrants = [c.removeprefix("pct:") for c in cases.columns if c.startswith("pct:")]
    out = []
    groups = [(p, cases[cases["protocol"] == p]) for p in cases["protocol"].unique()]
    for protocol, g in [*groups, ("all", cases)]:
        row = {"protocol": protocol, "cases": len(g),
               "regret_median": float(g["regret"].median()),
               "regret_max": float(g["regret"].max()), "losses": int(g["loss"].sum()),
               "loss_pct": 100.0 * float(g["loss"].mean()) if len(g) else np.nan,
               "harmful": int(g["harmful"].sum()),
               "harmful_mean_norm": int(g["harmful_mean_norm"].sum()),
               "needless_fail": int(g["needless_fail"].sum()),
               "losses_peers": int(g["loss_peers"].sum()),
               "harmful_compass": int(g["harmful_compass"].sum()),
               "needless_fail_compass": int(g["needless_fail_compass"].sum()),
               "direction_cases": int(np.isfinite(g["raw_direction_deg"].to_numpy(float)).sum()),
               "losses_direction": int(g["loss_direction"].sum()),
               "heading_cases": int(np.isfinite(g["raw_heading_deg"].to_numpy(float)).sum()),
               "losses_heading": int(g["loss_heading"].sum()),
               "losses_compass": int(g["loss_compass"].sum()),
               "losses_oracle": int(g["loss_oracle"].sum()),
               "losses_compass_oracle": int(g["loss_compass_oracle"].sum()),
               "losses_recording_best": int(g["loss_recording_best"].sum()),
               "one_tied": int((g["tied"] == 1).sum()),
               "passed_over": int((g["passed_over"].fillna("") != "").sum()),
               "not_written": int((~g["written"].astype(bool)).sum())}
        for e in entrants:
            w, t, l_ = _wtl(g["auto_pct"].to_numpy(float), g[f"pct:{e}"].to_numpy(float))
            row[f"wtl:{e}"] = f"{w}/{t}/{l_}"
        out.append(row)
    return pd.DataFrame(out)
