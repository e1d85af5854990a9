"""The one configuration check: every command's composed config is checked here, once.

A bad value gives :class:`UsageError`, printed as one line naming the key and what is expected,
with exit status 2, before any result is touched. Each study gets its settings from one
builder here (:func:`review_study`, :func:`gyro_study`, :func:`real_study`,
:func:`wushi_study`); ``calibrate`` uses the same checks for its keys.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from omegaconf import DictConfig, OmegaConf

from magbench.core.units import Units, parse_field, parse_units
from magbench.engine.plugins import load_plugins
from magbench.methods.registry import get_method, methods

# Each study is imported by its own builder, so that a command loads only what it runs
# (``calibrate`` starts in a third of the time without the gyro and Wu-Shi studies).
if TYPE_CHECKING:
    from magbench.sources.synthetic import Point
    from magbench.studies.gyro import GyroStudy
    from magbench.studies.real import RealStudy
    from magbench.studies.review import OptionAxis, ReviewStudy
    from magbench.studies.wushi import WuShiStudy

__all__ = ["KINDS", "UsageError", "check_columns", "check_common", "check_field_strength",
           "check_instance", "check_integer", "check_number", "check_options",
           "check_out_calibration", "check_units", "compose_config", "config_dir", "gyro_study",
           "real_study", "review_study", "selected_algorithms", "study_for", "writable_folder",
           "wushi_study"]

#: Sweep kinds: the review's sweeps and coverage are "review"; the others name their study.
KINDS = ("review", "gyro", "real", "wushi")


class UsageError(Exception):
    """A bad command line or configuration value; printed as one line, exit status 2."""


def config_dir() -> Path:
    """The configuration folder: ``$MAGBENCH_CONF``, the repository's ``conf/``, or the copy
    installed with the package (``magbench/conf``)."""
    env = os.environ.get("MAGBENCH_CONF")
    here = Path(__file__).resolve()
    candidates = [Path(env)] if env else [here.parents[3] / "conf", here.parents[1] / "conf"]
    for path in candidates:
        if (path / "config.yaml").exists():
            return path
    raise UsageError(f"configuration folder not found (looked in "
                     f"{', '.join(map(str, candidates))}); reinstall magbench or set "
                     "MAGBENCH_CONF")


def compose_config(overrides: Sequence[str]) -> DictConfig:
    """Compose ``conf/config.yaml`` with Hydra overrides (``key=value`` strings)."""
    from hydra import compose, initialize_config_dir
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
            return compose(config_name="config", overrides=list(overrides))
    except (HydraException, OmegaConfBaseException) as exc:
        # Hydra's messages span lines and append its search path; keep the part that helps.
        text = " ".join(str(exc).split()).split(" Config search path")[0]
        raise UsageError(text) from None


def check_integer(value: object, what: str, low: int, high: int | None = None) -> int:
    """``value`` if it is an integer in [``low``, ``high``]; otherwise a :class:`UsageError`
    naming it."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise UsageError(f"{what} must be an integer >= {low}, got {value!r}")
    if high is not None and value > high:
        raise UsageError(f"{what} must be an integer <= {high}, got {value!r}")
    return value


#: The most trials a sweep accepts: its work units are listed in memory before the run (a
#: million trials of eight points is 8e6 units, about 1 GB), and 250 is the review's size.
MAX_TRIALS = 1_000_000


def check_columns(cfg: DictConfig, default: list | None = None) -> list | None:
    """The ``columns`` key of calibrate and apply: three names or 0-based positions, or
    ``default`` when unset (calibrate: find them; apply: those the calibration recorded)."""
    columns = cfg.get("columns")
    if columns is None:
        return default
    if OmegaConf.is_list(columns):
        return list(OmegaConf.to_container(columns))
    raise UsageError(f"columns must be a list of three names or positions, e.g. "
                     f"columns=[mx,my,mz] or columns=[0,1,2], got {columns!r}")


def check_number(value: object, what: str, ok: Callable[[float], bool], expected: str) -> float:
    """``value`` as a float if it is a finite number for which ``ok`` holds."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise UsageError(f"{what} must be a number {expected}, got {value!r}")
    if not ok(float(value)):
        raise UsageError(f"{what} must be {expected}, got {value!r}")
    return float(value)


def _plain(node: object) -> object:
    return OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node


def selected_algorithms(cfg: DictConfig, include_gyro: bool = False) -> list[str]:
    """The method names of ``algorithms=`` ('all' or a list), checked against the registry.

    'all' means every magnetometer-only method, plus the gyro-aided ones with
    ``include_gyro`` (for data that have angular rate: the gyro sweep, real recordings).
    """
    known = methods()
    chosen = _plain(cfg.algorithms)
    if chosen == "all":
        return [m for m in known if include_gyro or not get_method(m).needs_gyro]
    chosen = [chosen] if isinstance(chosen, str) else list(chosen or [])
    unknown = [a for a in chosen if a not in known]
    if unknown or not chosen:
        raise UsageError(f"unknown algorithm(s) {', '.join(map(str, unknown)) or '(none given)'}"
                         f"; expected 'all' or a list from: {', '.join(known)}")
    return chosen


def check_options(cfg: DictConfig, algorithms: Sequence[str]) -> dict[str, dict]:
    """``options.<method>.<option>`` values, each naming a selected method and one of its
    options (:meth:`magbench.methods.registry.Method.option_names`)."""
    options = _plain(cfg.get("options")) or {}
    if not isinstance(options, dict):
        raise UsageError("options must map method names to option dicts, e.g. "
                         "options.magical.max_iter=100")
    out = {}
    for name, opts in options.items():
        if name not in algorithms:
            raise UsageError(f"options given for {name!r}, which is not among the selected "
                             f"algorithms ({', '.join(algorithms)})")
        if not isinstance(opts, dict):
            raise UsageError(f"options.{name} must map option names to values, e.g. "
                             f"options.{name}.<option>=<value>, got {opts!r}")
        accepted = get_method(name).option_names()
        bad = sorted(set(opts) - set(accepted))
        if bad:
            raise UsageError(f"unknown option(s) {', '.join(bad)} for {name}; it accepts: "
                             f"{', '.join(accepted) or 'no options'}")
        out[name] = dict(opts)
    return out


def check_common(cfg: DictConfig) -> dict:
    """Keys every sweep shares: seed, n_jobs, chunk_size, delta, backend, call_timeout_s,
    plugins (imported here, so their methods are known to the checks that follow)."""
    plugins = [str(p) for p in (_plain(cfg.get("plugins")) or [])]
    try:
        load_plugins(plugins)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    n_jobs = cfg.n_jobs
    if isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs == 0:
        raise UsageError(f"n_jobs must be a non-zero integer (-1 = every core), got {n_jobs!r}")
    if cfg.backend not in ("loky", "dask"):
        raise UsageError(f"backend must be 'loky' or 'dask', got {cfg.backend!r}")
    timeout = cfg.call_timeout_s
    return {
        "seed": check_integer(cfg.seed, "seed", 0),
        "n_jobs": n_jobs,
        "chunk_size": check_integer(cfg.chunk_size, "chunk_size", 1),
        "delta": check_number(cfg.delta, "delta", lambda d: 0 < d < 1, "in (0, 1)"),
        "backend": str(cfg.backend),
        "scheduler_address": cfg.get("scheduler_address"),
        "call_timeout_s": None if timeout is None else check_number(
            timeout, "call_timeout_s", lambda t: t > 0, "> 0 seconds (or null for no limit)"),
        "plugins": tuple(plugins),
        "progress": bool(cfg.progress),
        "overwrite": _flag(cfg.get("overwrite", False), "overwrite"),
        "results_dir": _results_dir(cfg),
    }


def _flag(value: object, key: str) -> bool:
    if not isinstance(value, bool):
        raise UsageError(f"{key} must be true or false, got {value!r}")
    return value


def _results_dir(cfg: DictConfig) -> Path:
    path = Path(str(cfg.results_dir)).expanduser()
    for parent in [path, *path.parents]:
        if parent.exists():
            if not parent.is_dir():
                raise UsageError(f"results_dir {path} cannot be created: {parent} is a file; "
                                 "expected a folder")
            if not os.access(parent, os.W_OK | os.X_OK):
                raise UsageError(f"results_dir {path} is not writable ({parent}); choose a "
                                 "folder you can write to")
            break
    return path


def _trials(cfg: DictConfig, what: str) -> int:
    if cfg.get("trials") is None:
        raise UsageError(f"trials must be set for {what}")
    return check_integer(cfg.trials, "trials", 1, MAX_TRIALS)


def _nominal(cfg: DictConfig, min_k: int) -> Point:
    from magbench.sources.synthetic import Point
    from magbench.studies.review import POINT_COLUMNS

    nominal = cfg.nominal
    alpha = _plain(nominal.alpha)
    if not isinstance(alpha, list) or len(alpha) != 2:
        raise UsageError(f"nominal.alpha must be a list [low, high], got {alpha!r}")
    lo = check_number(alpha[0], "nominal.alpha[0]", lambda a: a > 0, "> 0")
    hi = check_number(alpha[1], "nominal.alpha[1]", lambda a: a >= lo, f">= {lo}")
    for key in POINT_COLUMNS:
        if key in nominal:
            check_number(nominal[key], f"nominal.{key}", *_POINT_CHECKS(min_k)[key])
    return Point(int(nominal.K), float(nominal.sigma), float(nominal.beta),
                 float(nominal.gamma), lo, hi)


def _POINT_CHECKS(min_k: int) -> dict:
    return {"K": (lambda k: k >= min_k and k == int(k),
                  f"an integer >= {min_k} (the largest minimum of the chosen methods)"),
            "sigma": (lambda s: s >= 0, ">= 0"), "beta": (lambda b: b >= 0, ">= 0"),
            "gamma": (lambda g: g >= 0, ">= 0"),
            "cap_deg": (lambda c: 0 < c <= 180, "in (0, 180] degrees"),
            "band_deg": (lambda b: 0 < b <= 90, "in (0, 90] degrees")}


def review_study(cfg: DictConfig) -> tuple[ReviewStudy, dict]:
    """The review sweep (baseline, gamma, beta, K, sigma, coverage) and the common values."""
    from magbench.studies.review import POINT_COLUMNS, ReviewStudy, point_with

    common = check_common(cfg)
    algorithms = selected_algorithms(cfg)
    min_k = max(get_method(a).min_samples for a in algorithms)
    base = _nominal(cfg, min_k)
    sweep = cfg.sweep
    vary = sweep.get("vary")
    values = list(_plain(sweep.get("values")) or [])
    if vary and not values:
        raise UsageError(f"sweep {sweep.name!r} varies {vary} but lists no values")
    axis = None
    if isinstance(vary, str) and vary.startswith("options."):
        # A method's option varied on the same datasets, at the nominal point.
        axis = _option_axis(vary, values, algorithms)
        vary = None
    if vary is not None and vary not in POINT_COLUMNS:
        raise UsageError(f"sweep.vary must be one of {', '.join(POINT_COLUMNS)}, "
                         f"options.<method>.<option> or null, got {vary!r}")
    # A sweep either varies one parameter over `values`, or lists its points explicitly as
    # changes to the nominal point (`points: [{cap_deg: 90}, {band_deg: 10}]`).
    changes = ([{vary: v} for v in values] if vary else
               [dict(c) for c in (sweep.get("points") or [{}])])
    checks = _POINT_CHECKS(min_k)
    for change in changes:
        for key, v in change.items():
            if key not in checks:
                raise UsageError(f"sweep point sets {key!r}; a point has "
                                 f"{', '.join(POINT_COLUMNS)}")
            check_number(v, f"sweep value {key}", *checks[key])
    study = ReviewStudy(str(sweep.name), [point_with(base, c) for c in changes],
                        _trials(cfg, f"sweep {sweep.name}"), common["seed"], algorithms,
                        check_options(cfg, algorithms), common["delta"],
                        common["call_timeout_s"], common["plugins"], axis)
    return study, common


def _option_axis(vary: str, values: list, algorithms: Sequence[str]) -> OptionAxis:
    """The :class:`OptionAxis` of ``sweep.vary=options.<method>.<option>``, checked."""
    from magbench.studies.review import OptionAxis

    try:
        axis = OptionAxis.parse(vary, values)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if axis.method not in algorithms:
        raise UsageError(f"sweep.vary {vary} names {axis.method!r}, which is not among the "
                         f"selected algorithms ({', '.join(algorithms)})")
    accepted = get_method(axis.method).option_names()
    if axis.option not in accepted:
        raise UsageError(f"sweep.vary {vary}: {axis.method} has no option {axis.option!r}; it "
                         f"accepts: {', '.join(accepted) or 'no options'}")
    if any(v is None or isinstance(v, bool | dict) for v in values):
        raise UsageError(f"sweep.values of {vary} must be numbers, strings or lists, got "
                         f"{values!r}")
    return axis


def gyro_study(cfg: DictConfig) -> tuple[GyroStudy, dict]:
    """The gyro sweep: coverages x gyro noise levels, ``trials`` manoeuvres each."""
    from magbench.studies.gyro import DEFAULT_COVERAGES, GyroPoint, GyroStudy

    common = check_common(cfg)
    sweep = cfg.sweep
    coverages = _plain(sweep.get("coverages")) or dict(DEFAULT_COVERAGES)
    chosen = list(_plain(sweep.get("coverage")) or coverages)
    unknown = [c for c in chosen if c not in coverages]
    if unknown:
        raise UsageError(f"unknown coverage(s) {', '.join(map(str, unknown))}; defined: "
                         f"{', '.join(coverages)}")
    noises = [check_number(g, "sweep.gyro_noise", lambda x: x >= 0, ">= 0 rad/s")
              for g in (_plain(sweep.get("gyro_noise")) or [0.0])]
    rate = check_number(sweep.get("rate_hz", 25.0), "sweep.rate_hz", lambda r: r > 0, "> 0 Hz")
    duration = check_number(sweep.get("duration_s", 24.0), "sweep.duration_s",
                            lambda d: d > 0, "> 0 s")
    bias = check_number(sweep.get("gyro_bias_max", 0.02), "sweep.gyro_bias_max",
                        lambda b: b >= 0, ">= 0 rad/s")
    algorithms = selected_algorithms(cfg, include_gyro=True)
    nominal = _nominal(cfg, 4)
    study = GyroStudy(points=[GyroPoint(c, g, nominal.sigma) for c in chosen for g in noises],
                      trials=_trials(cfg, "sweep gyro"), seed=common["seed"],
                      algorithms=algorithms, options=check_options(cfg, algorithms),
                      coverages=coverages, rate_hz=rate, duration_s=duration,
                      beta=nominal.beta, gamma=nominal.gamma,
                      alpha=(nominal.alpha_low, nominal.alpha_high), gyro_bias_max=bias,
                      delta=common["delta"], call_timeout_s=common["call_timeout_s"],
                      plugins=common["plugins"], name=str(sweep.name))
    return study, common


def real_study(cfg: DictConfig) -> tuple[RealStudy, dict]:
    """The real-data sweep over the recordings in ``data_dir`` (one fit per recording: no
    trials)."""
    from magbench.sources.recordings import data_dir, list_recordings
    from magbench.studies.real import DEFAULT_MAX_SAMPLES, PREPROCESSING, RealStudy

    common = check_common(cfg)
    if cfg.get("trials") is not None:
        raise UsageError("trials does not apply to sweep=real (every recording is fitted once, "
                         "deterministically); drop trials=")
    try:
        root = data_dir(cfg.get("data_dir"))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    sweep = cfg.sweep
    known = list_recordings(root)
    chosen = _plain(sweep.get("datasets", "all"))
    chosen = known if chosen == "all" else [chosen] if isinstance(chosen, str) else list(chosen)
    unknown = [d for d in chosen if d not in known]
    if unknown or not chosen:
        raise UsageError(f"unknown recording(s) {', '.join(map(str, unknown)) or '(none)'} in "
                         f"{root}; expected 'all' or a list from: {', '.join(known)}")
    preprocess = _plain(sweep.get("preprocess", ["scale", "centre"]))
    preprocess = [preprocess] if isinstance(preprocess, str) else list(preprocess)
    bad = [p for p in preprocess if p not in PREPROCESSING]
    if bad or not preprocess:
        raise UsageError(f"sweep.preprocess must be a list from {', '.join(PREPROCESSING)}, "
                         f"got {preprocess}")
    algorithms = selected_algorithms(cfg, include_gyro=True)
    study = RealStudy(
        str(root), chosen, algorithms, tuple(preprocess),
        check_integer(sweep.get("max_samples", DEFAULT_MAX_SAMPLES), "sweep.max_samples", 8),
        check_options(cfg, algorithms), common["seed"], common["call_timeout_s"],
        check_number(sweep.get("coverage_ratio", 0.5), "sweep.coverage_ratio",
                     lambda r: 0 <= r <= 1, "in [0, 1]"),
        check_number(sweep.get("sphere_factor", 2.0), "sweep.sphere_factor",
                     lambda f: f > 0, "> 0"),
        common["plugins"], str(sweep.name))
    return study, common


def wushi_study(cfg: DictConfig) -> tuple[WuShiStudy, dict]:
    """Wu and Shi's simulation study: ``trials`` Monte Carlo runs of their section IV."""
    from magbench.studies.wushi import ML, NM, WuShiStudy

    common = check_common(cfg)
    s = cfg.sweep

    def integer(key: str, default: int, low: int = 1) -> int:
        return check_integer(s.get(key, default), f"sweep.{key}", low)

    algorithms = selected_algorithms(cfg)
    min_n = max(get_method(m).min_samples for m in dict.fromkeys([ML, NM, *algorithms]))
    N = integer("N", 300, min_n)
    sigma = check_number(s.get("sigma", 0.003), "sweep.sigma", lambda x: x >= 0, ">= 0")
    alphas = [check_number(a, "sweep.alphas_pct", lambda x: x >= 0, ">= 0")
              for a in _plain(s.get("alphas_pct", [0, 1, 2, 3, 4, 5, 6, 7]))]
    time_N = [check_integer(n, "sweep.time_N", min_n)
              for n in _plain(s.get("time_N", [100, 200, 500, 1000, 2000, 3000]))]
    thresholds = _plain(s.get("thresholds", {"ML": 0.004, "NM": 0.018}))
    if not isinstance(thresholds, dict) or set(thresholds) != {"ML", "NM"}:
        raise UsageError(f"sweep.thresholds must have keys ML and NM, got {thresholds!r}")
    study = WuShiStudy(
        runs=_trials(cfg, "sweep wushi"), N=N, sigma=sigma, seed=common["seed"],
        algorithms=tuple(algorithms), alphas_pct=tuple(alphas),
        thresholds={k: check_number(v, f"sweep.thresholds.{k}", lambda x: x > 0, "> 0")
                    for k, v in thresholds.items()},
        time_N=tuple(time_N), time_repeats=integer("time_repeats", 5),
        time_calls=integer("time_calls", 3), max_iter=integer("max_iter", 50),
        converge_within=integer("converge_within", 5),
        control_runs=integer("control_runs", 10, low=0),
        claimed_ratio=check_number(s.get("claimed_ratio", 10.0), "sweep.claimed_ratio",
                                   lambda x: x > 0, "> 0"),
        options=check_options(cfg, [*dict.fromkeys([ML, NM, *algorithms])]),
        call_timeout_s=common["call_timeout_s"],
        plugins=common["plugins"], name=str(s.name))
    return study, common


#: The ``sweep.*`` keys each kind reads; any other is refused rather than silently ignored
#: (``+sweep.trials=0`` once ran a full gyro sweep: the count is the top-level ``trials``).
SWEEP_KEYS = {
    "review": ("name", "kind", "vary", "values", "points"),
    "gyro": ("name", "kind", "vary", "values", "rate_hz", "duration_s", "gyro_bias_max",
             "gyro_noise", "coverage", "coverages"),
    "real": ("name", "kind", "vary", "values", "datasets", "max_samples", "preprocess",
             "coverage_ratio", "sphere_factor"),
    "wushi": ("name", "kind", "vary", "values", "N", "sigma", "alphas_pct", "thresholds",
              "max_iter", "converge_within", "time_N", "time_repeats", "time_calls",
              "claimed_ratio", "control_runs"),
}


def study_for(cfg: DictConfig):
    """The study and common values of the sweep chosen by ``sweep=``."""
    kind = cfg.sweep.get("kind", "review")
    builders = {"review": review_study, "gyro": gyro_study, "real": real_study,
                "wushi": wushi_study}
    if kind not in builders:
        raise UsageError(f"sweep.kind must be one of {', '.join(KINDS)}, got {kind!r}")
    unknown = [str(k) for k in cfg.sweep if k not in SWEEP_KEYS[kind]]
    if unknown:
        hint = (" (the number of trials is the top-level key: trials=N)"
                if "trials" in unknown else "")
        raise UsageError(f"unknown key(s) sweep.{', sweep.'.join(unknown)} for a {kind} sweep"
                         f"{hint}; it reads sweep.{', sweep.'.join(SWEEP_KEYS[kind][2:])}")
    return builders[kind](cfg)


def writable_folder(path: Path | str, key: str) -> Path:
    """``path`` as a folder that exists and can be written to, created if need be.

    Tries it rather than trusting permission bits (``os.access`` says yes to root even where
    the file system refuses), so every path problem is found here, before any work.

    Raises
    ------
    UsageError
        ``path`` or one of its parents is a file, or the folder cannot be created or written.
    """
    path = Path(path).expanduser()
    for parent in [path, *path.parents]:
        if parent.exists() and not parent.is_dir():
            what = "is" if parent == path else f"cannot be created: {parent} is"
            raise UsageError(f"{key}={path} {what} a file; expected a folder")
        if parent.exists():
            break
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise UsageError(f"{key}={path} cannot be written ({exc.strerror or exc}); choose a "
                         "folder you can write to") from None
    return path



def check_units(cfg: DictConfig) -> Units:
    """``units`` of calibrate: a unit, ``counts`` or a count's size (:mod:`magbench.core.units`);
    unset means unknown."""
    try:
        return parse_units(_plain(cfg.get("units")))
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def check_field_strength(cfg: DictConfig, units: Units) -> float | None:
    """``field_strength`` of calibrate: the expected field, in file units or with a unit
    (``48uT``), converted to file units; None when unset."""
    try:
        return parse_field(_plain(cfg.get("field_strength")), units)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def check_instance(cfg: DictConfig) -> str | None:
    """``instance``: the value of the sensor-instance column to keep (compared as text, so
    ``instance=1`` matches a cell ``1``); None when unset."""
    value = _plain(cfg.get("instance"))
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, str | int | float):
        raise UsageError(f"instance must be one value of the file's instance column, e.g. "
                         f"instance=1, got {value!r}")
    return str(value)


def check_out_calibration(out: Path, overwrite: object) -> None:
    """Refuse an ``out`` folder that already holds a calibration unless ``overwrite=true``."""
    if _flag(overwrite if overwrite is not None else False, "overwrite"):
        return
    if (Path(out).expanduser() / "calibration.json").exists():
        raise UsageError(f"out={out} already holds a calibration (calibration.json); pass "
                         "overwrite=true to replace it, or choose another out=")
