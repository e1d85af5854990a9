"""The heading study: which calibration points the right way, and does J tell?

Every registered method is scored by the direction of the field it gives
(:mod:`magbench.core.direction`): BROAD's heading and inclination errors against a reference
attitude, the spread of the world-frame field direction, the gyro consistency and the dip
spread, beside the magnitude metrics J (eq. 74, where the truth is known) and J_r (eq. 81).
Three parts, one row per (unit, method):

``mc``
    Monte Carlo: :func:`magbench.sources.trajectory.simulate` with an accelerometer, a mounting
    rotation of 0 to ``mount_max_deg`` about a random axis, noise and a magnetometer lag up to
    ``lag_max_s``; ``T = alpha I + E`` and ``h = e`` from eq. (68) at the nominal point. The
    lag is measured (:func:`magbench.core.lag.magnetometer_lag`, gyro against the samples
    after a closed-form ellipsoid fit) and removed before the fit. ``crb_heading`` is the floor of
    :func:`magbench.core.direction.heading_bound` for a calibration that knows the attitude.
``semi``
    Semi-synthetic: each recording (prepared by :func:`magbench.sources.semisynthetic.prepare`:
    lags removed, clean rows, reference field) with ``draws`` known distortions per kind
    (``eq80``: eq. 68 at eq. 80; ``magnet``: plus an attached magnet) and a mounting rotation
    of ``mount_deg``. Methods fit the clean rows (thinned to ``max_samples``); the heading is
    scored on the clean rows of the movement phase.
``given``
    The recordings as given (lag removed, scaled by the reference field strength), every row
    fitted (thinned), disturbances included; scored on the clean rows of the movement phase
    (no calibration can undo a magnet that comes and goes: the question is whether the
    disturbed rows in the fit spoil the heading elsewhere).

Every method gets the samples after the ``preprocess`` of :func:`magbench.pipeline.fitting.
fit_recording` (``centre`` by default, as ``calibrate`` does: an attached magnet's offset
exceeds the field radius) and its estimate is mapped back.

*Which rotation is scored.* A magnetometer-only method cannot know the sensor's rotation
(eq. 70): what it writes is the symmetric gauge of :meth:`Calibration.safe`, and that is what
is scored. A calibration with an ``alignment`` (the rotation from that gauge to the inertial
axes) is scored heading-true, ``R A (y - h)``; another method that receives inertial data
(gyro, attitude) can fix the rotation in its ``T``, which is scored as returned (``gauge``:
``heading-true``, ``returned`` or ``symmetric``). A method that needs an input a part cannot
give (``needs_*`` of the registry, or a required keyword such as an accelerometer the
recording lacks) gives a row with ``ok=False`` and the reason. ``heading_floor`` is the
heading error of the true calibration (``semi``, ``mc``) or of the recording as given
(``given``).
"""

from __future__ import annotations

import contextlib
import functools
import inspect
import io
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd

from magbench.core.direction import direction_score, heading_bound
from magbench.core.files import atomic_path, file_sha256, write_csv_atomic
from magbench.core.gauge import symmetric_T
from magbench.core.lag import magnetometer_lag, shift
from magbench.core.metrics import accuracy_cost, real_cost
from magbench.core.model import Calibration
from magbench.core.quaternions import quat_to_matrix
from magbench.core.seeding import rng
from magbench.engine.record import study_code
from magbench.engine.sweep import Study, settings_hash
from magbench.engine.trial import estimate_columns, run_method
from magbench.methods.api import calibrate
from magbench.methods.registry import get_method
from magbench.pipeline.fitting import fit_recording
from magbench.sources.recordings import InertialRecording, Recording, read_inertial
from magbench.sources.semisynthetic import (
    DISTORTIONS,
    Prepared,
    distort,
    prepare,
    random_rotation,
)
from magbench.sources.synthetic import Point, draw_distortion
from magbench.sources.trajectory import simulate
from magbench.studies.review import TIME_COLUMNS, TRUTH_COLUMNS, read_trials, truth_columns
from magbench.studies.times import split_times

__all__ = ["HEADING_ROW_COLUMNS", "PARTS", "PREPARED_CACHE", "HeadingStudy", "Scene",
           "correlations", "heading_rows", "scored_field", "summarize_heading"]

PARTS = ("mc", "semi", "given")
_SCORES = ["heading_rms", "heading_median", "heading_p95", "inclination_rms",
           "spread_median", "spread_rms", "spread_p95", "gyro_median", "dip_spread"]
HEADING_ROW_COLUMNS = (
    ["part", "dataset", "distortion", "trial", "seed", "algorithm", "inputs", "gauge", "ok",
     "error", "n_iter", "K_fit", "J", "J_h", "J_T", "J_r"] + _SCORES
    + ["heading_floor", "crb_heading", "crb_alignment", "mount_deg", "lag_true_ms", "lag_ms",
       "gyro_lag_ms"]
    + TRUTH_COLUMNS + [f"h_{i}" for i in range(3)]
    + [f"T_{i}{j}" for i in range(3) for j in range(3)])

#: What a part can hand a method, by the keyword the method's ``fit`` takes.
_INPUT_KEYS = {"angular_rate": "gyro", "time": "t", "acceleration": "acceleration",
               "accelerometer": "acceleration", "specific_force": "acceleration",
               "attitude": "R", "reference_field": "m0"}


@dataclass(frozen=True)
class Scene:
    """One unit's data: what the methods fit and what their field is scored on.

    ``fit`` and ``score`` map stream names (``y``, ``t``, ``gyro``, ``acceleration``, ``R``,
    ``attitude``, ``m0``) to arrays; ``score`` also has ``mask`` (rows scored with the
    attitude) and ``reference`` (world field). ``truth`` is ``(T M, h)`` where known.
    """

    fit: dict
    score: dict
    truth: tuple[np.ndarray, np.ndarray] | None
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class HeadingStudy(Study):
    """Everything that determines the heading study's rows (see the module notes)."""

    algorithms: Sequence[str] = ()
    parts: Sequence[str] = PARTS
    trials: int = 6
    root: str | None = None
    datasets: Sequence[str] = ()
    distortions: Sequence[str] = DISTORTIONS
    draws: int = 1
    options: dict = field(default_factory=dict)
    seed: int = 2021
    max_samples: int = 2000
    preprocess: str = "centre"
    mount_deg: float = 3.0
    tolerance: float = 0.1
    rate_hz: float = 25.0
    duration_s: float = 20.0
    rate_rms: float = 1.0
    sigma: float = 0.005
    gyro_noise: float = 0.005
    accel_noise: float = 0.05
    gyro_bias_max: float = 0.02
    mount_max_deg: float = 10.0
    lag_max_s: float = 0.03
    correct_lag: bool = True
    point: Point = field(default_factory=Point)
    call_timeout_s: float | None = None
    plugins: Sequence[str] = ()
    name: str = "heading"
    #: A folder where each recording's preparation is kept for the next run (a method
    #: added prepares nothing again); it determines no row, so it is no setting.
    cache: str | None = field(default=None, compare=False, repr=False,
                              metadata={"setting": False})

    #: Rows are cached per method (:mod:`magbench.engine.sweep`): one row per method and unit.
    method_column: ClassVar[str] = "algorithm"
    tables: ClassVar[dict] = {"trials": ("heading_trials.csv", HEADING_ROW_COLUMNS),
                              "times": ("heading_trials_times.csv", TIME_COLUMNS)}

    def units(self) -> list[tuple[str, str, str, int]]:
        out: list[tuple[str, str, str, int]] = []
        if "mc" in self.parts:
            out += [("mc", "", "", t) for t in range(self.trials)]
        if "semi" in self.parts:
            out += [("semi", d, k, i) for d in self.datasets for k in self.distortions
                    for i in range(self.draws)]
        if "given" in self.parts:
            out += [("given", d, "", 0) for d in self.datasets]
        return out

    def run_unit(self, unit: tuple[str, str, str, int]) -> dict[str, list[dict]]:
        rows, times = split_times(heading_rows(self, *unit), "trial")
        return {"trials": rows, "times": times}

    def summarize(self, out_dir: Path | str) -> pd.DataFrame:
        """Write ``summary.csv`` (per part and method) and ``correlation.csv`` (Spearman's
        rank correlation of the heading error with J and J_r, per dataset and pooled)."""
        out_dir = Path(out_dir)
        trials = read_trials(out_dir / "heading_trials.csv")
        summary = summarize_heading(trials)
        write_csv_atomic(summary, out_dir / "summary.csv")
        write_csv_atomic(correlations(trials), out_dir / "correlation.csv")
        return summary


def _prepared(root: str, name: str, tolerance: float, correct_lag: bool,
              cache: str | None = None) -> Prepared:
    """A recording read and prepared once per process (every unit of it reuses it), and with
    a ``cache`` folder once per recording file, preparation code and options.

    Raises
    ------
    ValueError
        If the recording cannot be prepared (:func:`~magbench.sources.semisynthetic.prepare`).
    """
    found = _prepared_or_reason(root, name, tolerance, correct_lag, cache)
    if isinstance(found, str):
        raise ValueError(found)
    return found


#: The folder, in the study's results folder, of the recordings as prepared
#: (``<recording>-<key>.npz``, :func:`_prepared`).
PREPARED_CACHE = "prepared"
#: Bumped when what :func:`_prepared_arrays` keeps changes: older files are not read.
_PREPARED_FORMAT = 1
_REC_ARRAYS = ("t", "y", "gyro", "acceleration", "attitude")


@functools.lru_cache(maxsize=8)
def _prepared_or_reason(root: str, name: str, tolerance: float, correct_lag: bool,
                        cache: str | None) -> Prepared | str:
    """:func:`_prepared`'s work: the prepared recording, or why it cannot be prepared (kept
    too: a recording that fails would otherwise be prepared again for every unit)."""
    path = Path(root) / name / "data.csv"
    if cache is not None:
        kept = Path(cache) / f"{name}-{_prepared_key(path, tolerance, correct_lag)}.npz"
        if kept.is_file():
            with contextlib.suppress(OSError, ValueError, KeyError):
                return _from_arrays(name, kept)
    try:
        found: Prepared | str = prepare(read_inertial(path), tolerance=tolerance,
                                        correct_lag=correct_lag)
    except ValueError as exc:
        found = str(exc)
    if cache is None:
        return found
    with atomic_path(kept) as tmp:
        _write_npz(tmp, _prepared_arrays(found))
    for other in Path(cache).glob(f"{name}-*.npz"):   # a stale key's file, not needed again
        if other != kept and other.name[len(name) + 1:-4].isalnum():
            other.unlink(missing_ok=True)
    # What this run uses is what a later run reads back (the same arrays, bit for bit).
    return _from_arrays(name, kept)


def _prepared_key(path: Path, tolerance: float, correct_lag: bool) -> str:
    """What determines a prepared recording: the file's bytes, the code that reads and
    prepares it (:func:`~magbench.engine.record.study_code` of
    :mod:`magbench.sources.semisynthetic`, which covers the reader), its options, NumPy."""
    return settings_hash({"file": file_sha256(path), "code": _prepare_code(),
                          "tolerance": tolerance, "correct_lag": correct_lag,
                          "numpy": np.__version__, "format": _PREPARED_FORMAT})


@functools.lru_cache(maxsize=1)
def _prepare_code() -> str:
    return study_code(prepare.__module__)


def _prepared_arrays(p: Prepared | str) -> dict[str, np.ndarray]:
    """A prepared recording (or the reason it has none) as named arrays."""
    if isinstance(p, str):
        return {"error": np.array(p)}
    streams = {f"rec_{k}": getattr(p.rec, k) for k in _REC_ARRAYS
               if getattr(p.rec, k) is not None}
    return {**streams, "lags": np.array([p.lag_s, p.gyro_lag_s, p.mag_gyro_lag_s, p.strength]),
            "reference": p.reference, "clean": p.clean, "movement": p.movement}


def _from_arrays(name: str, path: Path) -> Prepared | str:
    """:func:`_prepared_arrays`' file read back."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    if "error" in arrays:
        return str(arrays["error"])
    rec = InertialRecording(name, **{k: arrays.get(f"rec_{k}") for k in _REC_ARRAYS})
    lag, g_lag, mg_lag, strength = (float(v) for v in arrays["lags"])
    return Prepared(rec, lag, g_lag, mg_lag, arrays["reference"], strength,
                    arrays["clean"], arrays["movement"])


def _write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """``np.savez``'s format with a fixed time stamp per member, so that the same arrays
    give the same bytes (a full and an incremental run leave equal folders)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as archive:
        for key, value in arrays.items():
            buffer = io.BytesIO()
            np.lib.format.write_array(buffer, np.asanyarray(value), allow_pickle=False)
            archive.writestr(zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0)),
                             buffer.getvalue())


def _stride(n: int, max_samples: int) -> int:
    return max(1, -(-n // max_samples))


def _recording_streams(p: Prepared, rows: np.ndarray, y: np.ndarray) -> dict:
    """The streams of the prepared recording at ``rows``, with magnetometer samples ``y``."""
    rec = p.rec
    return {"y": y[rows], "t": rec.t[rows], "gyro": rec.gyro[rows],
            "acceleration": None if rec.acceleration is None else rec.acceleration[rows],
            "R": quat_to_matrix(rec.attitude[rows]), "m0": p.reference / p.strength}


def _score_streams(p: Prepared, y: np.ndarray, mask: np.ndarray) -> dict:
    rec = p.rec
    return {"y": y, "t": rec.t, "gyro": rec.gyro, "acceleration": rec.acceleration,
            "attitude": rec.attitude, "mask": mask, "reference": p.reference}


def semi_scene(spec: HeadingStudy, dataset: str, kind: str, draw: int) -> Scene:
    """A known distortion of one prepared recording (module notes, ``semi``)."""
    p = _prepared(str(spec.root), dataset, spec.tolerance, spec.correct_lag, spec.cache)
    d = distort(rng(spec.seed, "heading", dataset, kind, draw), p, kind, point=spec.point,
                mount_deg=spec.mount_deg)
    ok = p.clean & np.isfinite(p.rec.attitude).all(axis=1)
    rows = np.flatnonzero(ok)[::_stride(int(ok.sum()), spec.max_samples)]
    return Scene(_recording_streams(p, rows, d.y),
                 _score_streams(p, d.y, ok & p.movement), (d.T, d.h),
                 {"mount_deg": spec.mount_deg, "lag_ms": 1e3 * p.lag_s,
                  "gyro_lag_ms": 1e3 * p.gyro_lag_s})


def given_scene(spec: HeadingStudy, dataset: str) -> Scene:
    """The recording as given, scaled by its field strength (module notes, ``given``)."""
    p = _prepared(str(spec.root), dataset, spec.tolerance, spec.correct_lag, spec.cache)
    y = p.rec.y / p.strength
    has = np.isfinite(p.rec.attitude).all(axis=1)
    rows = np.flatnonzero(has)[::_stride(int(has.sum()), spec.max_samples)]
    return Scene(_recording_streams(p, rows, y),
                 _score_streams(p, y, has & p.clean & p.movement), None,
                 {"lag_ms": 1e3 * p.lag_s, "gyro_lag_ms": 1e3 * p.gyro_lag_s})


def mc_scene(spec: HeadingStudy, trial: int) -> Scene:
    """One simulated manoeuvre with its lag measured and removed (module notes, ``mc``)."""
    g = rng(spec.seed, "heading", "mc", trial)
    T, h = draw_distortion(g, spec.point)
    bias = g.uniform(-spec.gyro_bias_max, spec.gyro_bias_max, size=3)
    angle = g.uniform(0.0, spec.mount_max_deg)
    M = random_rotation(g, angle)
    lag = g.uniform(0.0, spec.lag_max_s)
    tr = simulate(g, rate_hz=spec.rate_hz, duration_s=spec.duration_s, T=T, h=h,
                  mag_noise=spec.sigma, gyro_noise=spec.gyro_noise, gyro_bias=bias,
                  rate_rms=spec.rate_rms, mount=M, lag_s=lag, accel_noise=spec.accel_noise)
    # The lag is measured on a rough calibration (a closed-form ellipsoid fit): the
    # distortion left by a sphere fit biased it by up to a quarter of a sample.
    rough = calibrate(tr.y, "ellipsoid").safe().apply(tr.y)
    found, _ = magnetometer_lag(tr.t, rough, tr.angular_rate)
    y = shift(tr.t, tr.y, found) if spec.correct_lag and np.isfinite(found) else tr.y
    ok = np.isfinite(y).all(axis=1)
    q = tr.attitude
    streams = {"y": y[ok], "t": tr.t[ok], "gyro": tr.angular_rate[ok],
               "acceleration": tr.acceleration[ok], "R": tr.R[ok], "m0": tr.m0}
    score = {**streams, "attitude": q[ok], "mask": np.ones(int(ok.sum()), dtype=bool),
             "reference": tr.m0}
    # Resampling by a fraction f of a sample averages two noise draws: the samples scored
    # carry sigma sqrt((1-f)^2 + f^2), and so does the bound.
    f = float(np.mod(found * spec.rate_hz, 1.0)) if y is not tr.y else 0.0
    crb = heading_bound(T @ M, q[ok], tr.m0, spec.sigma * np.hypot(1.0 - f, f))
    return Scene(streams, score, (T @ M, h),
                 {"mount_deg": angle, "lag_true_ms": 1e3 * lag, "lag_ms": 1e3 * found,
                  "crb": crb})

def _inputs(name: str, fit: dict) -> tuple[dict, str]:
    """The inertial keywords ``name`` takes that the scene holds, and why it cannot run
    (empty if it can)."""
    spec = get_method(name)
    needs = [f.name[len("needs_"):] for f in spec.__dataclass_fields__.values()
             if f.name.startswith("needs_") and getattr(spec, f.name)]
    params = inspect.signature(spec.fit).parameters.values()
    keywords = [p for p in params if p.kind is inspect.Parameter.KEYWORD_ONLY]
    kwargs = {p.name: fit[_INPUT_KEYS[p.name]] for p in keywords
              if p.name in _INPUT_KEYS and fit.get(_INPUT_KEYS[p.name]) is not None}
    missing = [p.name for p in keywords if p.default is inspect.Parameter.empty
               and p.name not in kwargs and p.name != "rng"]
    if "gyro" in needs:
        needs.remove("gyro")
        missing += [k for k in ("angular_rate", "time") if k not in kwargs]
    known = {"acc": "acceleration", "accel": "acceleration", "accelerometer": "acceleration",
             "attitude": "R"}
    missing += [n for n in needs if fit.get(known.get(n, n)) is None]
    if spec.min_samples > len(fit["y"]):
        return kwargs, f"skipped: {name} needs {spec.min_samples} samples, got {len(fit['y'])}"
    if missing:
        return kwargs, (f"skipped: {name} needs {', '.join(dict.fromkeys(missing))}, which "
                        "this part does not provide")
    return kwargs, ""


def scored_field(cal: Calibration, y: np.ndarray, returned: bool) -> np.ndarray:
    """The field a calibration gives, in the gauge it would be used in (module notes).

    With an ``alignment`` ``R`` (the rotation from the symmetric gauge to the inertial axes,
    set by the alignment methods) the field is ``R A (y - h)``, ``A = (T T^T)^(-1/2)``;
    otherwise ``T^-1 (y - h)`` with ``T`` as returned when the method had inertial data
    (``returned``), else in the symmetric gauge.
    """
    alignment = getattr(cal, "alignment", None)
    if alignment is None and returned:
        return cal.apply(y)
    field_ = Calibration(symmetric_T(cal.T), cal.h).apply(y)
    return field_ if alignment is None else field_ @ np.asarray(alignment, dtype=float).T


def _gauge(cal: Calibration | None, returned: bool) -> str:
    if cal is not None and getattr(cal, "alignment", None) is not None:
        return "heading-true"
    return "returned" if returned else "symmetric"


def _scores(scene: Scene, field_: np.ndarray) -> dict:
    s = scene.score
    out = direction_score(field_, attitude=s["attitude"], reference=s["reference"],
                          mask=s["mask"], t=s["t"], angular_rate=s["gyro"],
                          acceleration=s["acceleration"])
    return {k: out[k] for k in _SCORES}


def _floor(scene: Scene) -> float:
    """Heading RMS of the true calibration (or of the samples as given)."""
    y = scene.score["y"]
    field_ = y if scene.truth is None else Calibration(*scene.truth).apply(y)
    return _scores(scene, field_)["heading_rms"]


def _method_row(spec: HeadingStudy, scene: Scene, name: str, stream: tuple) -> dict:
    kwargs, reason = _inputs(name, scene.fit)
    row = {"algorithm": name, "inputs": " ".join(sorted(kwargs)),
           "gauge": _gauge(None, bool(kwargs)), "K_fit": len(scene.fit["y"])}
    if reason:
        return {**row, "ok": False, "error": reason, "time_s": 0.0, "n_iter": 0,
                **estimate_columns(None, None)}
    y = scene.fit["y"]
    rec = Recording(name, y, scene.fit["t"], scene.fit["gyro"])
    out = run_method(name, lambda o: fit_recording(rec, name, spec.preprocess, o, kwargs),
                     options=spec.options.get(name) or {}, seed=spec.seed, stream=stream,
                     call_timeout_s=spec.call_timeout_s)
    row.update(ok=out.ok, error=out.error, time_s=out.time_s, n_iter=out.n_iter,
               gauge=_gauge(out.calibration, bool(kwargs)), **estimate_columns(out.T, out.h))
    if out.calibration is None:
        return row
    if scene.truth is not None:
        row["J"], row["J_h"], row["J_T"] = accuracy_cost(out.T, out.h, *scene.truth)
    row["J_r"] = real_cost(y, out.T, out.h)
    try:
        row.update(_scores(scene, scored_field(out.calibration, scene.score["y"],
                                               bool(kwargs))))
    except Exception as exc:  # a singular estimate has no field: a row, not a crash
        row.update(ok=False, error=f"scoring: {type(exc).__name__}: {exc}")
    return row


def heading_rows(spec: HeadingStudy, part: str, dataset: str, distortion: str,
                 trial: int) -> list[dict]:
    """Every selected method on one unit; one row per method (failures included: a
    recording that cannot be prepared, a lag outside the search say, gives each method a row
    with the reason)."""
    try:
        scene = (mc_scene(spec, trial) if part == "mc" else
                 semi_scene(spec, dataset, distortion, trial) if part == "semi" else
                 given_scene(spec, dataset))
    except ValueError as exc:
        blank = dict.fromkeys(HEADING_ROW_COLUMNS, np.nan)
        return [{**blank, "part": part, "dataset": dataset, "distortion": distortion,
                 "trial": int(trial), "seed": int(spec.seed), "algorithm": name,
                 "inputs": "", "gauge": "", "ok": False, "n_iter": 0, "K_fit": 0,
                 "error": f"not prepared: {exc}", "time_s": 0.0} for name in spec.algorithms]
    crb = scene.extra.get("crb", (np.nan, np.nan))
    base = {"part": part, "dataset": dataset, "distortion": distortion, "trial": int(trial),
            "seed": int(spec.seed), "heading_floor": _floor(scene), "crb_heading":
            float(np.degrees(crb[0])), "crb_alignment": float(np.degrees(crb[1])),
            **{k: scene.extra.get(k, np.nan) for k in ("mount_deg", "lag_true_ms", "lag_ms",
                                                       "gyro_lag_ms")},
            **truth_columns(*(scene.truth if scene.truth is not None
                              else (np.full((3, 3), np.nan), np.full(3, np.nan))))}
    stream = ("heading", part, dataset, distortion, int(trial))
    return [{**base, **_method_row(spec, scene, name, stream)} for name in spec.algorithms]


def summarize_heading(trials: pd.DataFrame) -> pd.DataFrame:
    """Per part and method: runs, ok runs and the medians of the heading and inclination RMS,
    the spread, J, J_r, the floor and the bound over the ok runs."""
    ok = trials[trials["ok"].astype(bool)]
    by = ["part", "algorithm"]
    counts = trials.groupby(by, sort=False).agg(n=("ok", "size")).reset_index()
    medians = ok.groupby(by, sort=False).agg(
        n_ok=("ok", "size"), heading_rms=("heading_rms", "median"),
        heading_p95=("heading_p95", "median"), inclination_rms=("inclination_rms", "median"),
        spread_median=("spread_median", "median"), gyro_median=("gyro_median", "median"),
        J=("J", "median"), J_r=("J_r", "median"), heading_floor=("heading_floor", "median"),
        crb_heading=("crb_heading", "median")).reset_index()
    out = counts.merge(medians, on=by, how="left")
    out["n_ok"] = out["n_ok"].fillna(0).astype(int)
    return out


def _spearman(a: pd.Series, b: pd.Series) -> tuple[float, int]:
    keep = np.isfinite(a.to_numpy(dtype=float)) & np.isfinite(b.to_numpy(dtype=float))
    if keep.sum() < 3:
        return np.nan, int(keep.sum())
    return float(a[keep].rank().corr(b[keep].rank())), int(keep.sum())


def correlations(trials: pd.DataFrame) -> pd.DataFrame:
    """Spearman's rank correlation of the heading RMS with J and with J_r over the ok rows,
    per (part, dataset) and pooled per part (``dataset = "pooled"``)."""
    ok = trials[trials["ok"].astype(bool)].copy()
    ok["dataset"] = ok["dataset"].astype(object).fillna("").replace("", "simulated")
    rows = []
    groups = [((part, ds), g) for (part, ds), g in ok.groupby(["part", "dataset"], sort=False)]
    groups += [((part, "pooled"), g) for part, g in ok.groupby("part", sort=False)
               if g["dataset"].nunique() > 1]
    for (part, ds), g in groups:
        rho_J, n_J = _spearman(g["heading_rms"], g["J"])
        rho_Jr, n_Jr = _spearman(g["heading_rms"], g["J_r"])
        rows.append({"part": part, "dataset": ds, "spearman_J": rho_J, "n_J": n_J,
                     "spearman_J_r": rho_Jr, "n_J_r": n_Jr})
    return pd.DataFrame(rows, columns=["part", "dataset", "spearman_J", "n_J", "spearman_J_r",
                                       "n_J_r"])
