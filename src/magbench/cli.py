"""Command line: Hydra-composed configuration, checked once, before any work.

``python -m magbench [COMMAND] [key=value ...]`` where COMMAND is ``run`` (the default: run the
sweep chosen by ``sweep=``) or ``report`` (regenerate tables from the CSV files). The
configuration is composed with Hydra's compose API from ``conf/`` so that a bad override gives
one clear line and exit status 2, without a traceback and before any result is touched.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

__all__ = ["UsageError", "compose_config", "main", "validate"]


class UsageError(Exception):
    """A bad command line or configuration value; printed as one line, exit status 2."""


def config_dir() -> Path:
    """``conf/`` of the repository (or ``$MAGBENCH_CONF``)."""
    env = os.environ.get("MAGBENCH_CONF")
    path = Path(env) if env else Path(__file__).resolve().parents[2] / "conf"
    if not (path / "config.yaml").exists():
        raise UsageError(f"configuration folder not found at {path}; install magbench from its "
                         "repository with `pip install -e .` or set MAGBENCH_CONF")
    return path


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


def check_integer(value: object, what: str, low: int) -> int:
    """``value`` if it is an integer >= ``low``; otherwise a :class:`UsageError` naming it."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise UsageError(f"{what} must be an integer >= {low}, got {value!r}")
    return value


def _integer(cfg: DictConfig, key: str, low: int) -> int:
    return check_integer(cfg[key], key, low)


def _number(value: object, what: str, ok: Callable[[float], bool], expected: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise UsageError(f"{what} must be a number {expected}, got {value!r}")
    if not ok(float(value)):
        raise UsageError(f"{what} must be {expected}, got {value!r}")
    return float(value)


def selected_algorithms(cfg: DictConfig, include_gyro: bool = False) -> list[str]:
    """The method names of ``algorithms=`` ('all' or a list), checked against the registry.

    'all' means every magnetometer-only method, plus the gyro-aided ones with
    ``include_gyro`` (for data that have angular rate, such as some real recordings).
    """
    from magbench.methods.registry import get_method, methods

    known = methods()
    chosen = cfg.algorithms
    if chosen == "all":
        # The static sweeps have no angular rate: 'all' is every magnetometer-only method.
        return [m for m in known if include_gyro or not get_method(m).needs_gyro]
    if isinstance(chosen, str):
        chosen = [chosen]
    chosen = list(chosen)
    unknown = [a for a in chosen if a not in known]
    if unknown or not chosen:
        raise UsageError(f"unknown algorithm(s) {', '.join(map(str, unknown)) or '(none given)'}"
                         f"; expected 'all' or a list from: {', '.join(known)}")
    return chosen


def validate(cfg: DictConfig) -> dict:
    """Check every value a sweep uses; returns the plain values, or raises :class:`UsageError`."""
    from magbench.engine.plugins import load_plugins
    from magbench.methods.registry import get_method
    from magbench.sources.synthetic import Point
    from magbench.studies.review import POINT_COLUMNS, point_with

    try:
        load_plugins(list(cfg.plugins or []))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = {
        "trials": _integer(cfg, "trials", 1),
        "seed": _integer(cfg, "seed", 0),
        "chunk_size": _integer(cfg, "chunk_size", 1),
        "delta": _number(cfg.delta, "delta", lambda d: 0 < d < 1, "in (0, 1)"),
        "algorithms": selected_algorithms(cfg),
    }
    if isinstance(cfg.n_jobs, bool) or not isinstance(cfg.n_jobs, int) or cfg.n_jobs == 0:
        raise UsageError(f"n_jobs must be a non-zero integer (-1 = every core), got "
                         f"{cfg.n_jobs!r}")
    out["n_jobs"] = cfg.n_jobs
    if cfg.backend not in ("loky", "dask"):
        raise UsageError(f"backend must be 'loky' or 'dask', got {cfg.backend!r}")
    timeout = cfg.call_timeout_s
    out["call_timeout_s"] = None if timeout is None else _number(
        timeout, "call_timeout_s", lambda t: t > 0, "> 0 seconds (or null for no limit)")
    nominal = cfg.nominal
    alpha = list(nominal.alpha) if OmegaConf.is_list(nominal.alpha) else None
    if alpha is None or len(alpha) != 2:
        raise UsageError(f"nominal.alpha must be a list [low, high], got {nominal.alpha!r}")
    lo = _number(alpha[0], "nominal.alpha[0]", lambda a: a > 0, "> 0")
    hi = _number(alpha[1], "nominal.alpha[1]", lambda a: a >= lo, f">= {lo}")
    sweep = cfg.sweep
    vary = sweep.get("vary")
    if vary is not None and vary not in POINT_COLUMNS:
        raise UsageError(f"sweep.vary must be one of {', '.join(POINT_COLUMNS)} or null, got "
                         f"{vary!r}")
    values = list(sweep.get("values") or [])
    if vary and not values:
        raise UsageError(f"sweep {sweep.name!r} varies {vary} but lists no values")
    # A sweep either varies one parameter over `values`, or lists its points explicitly as
    # changes to the nominal point (`points: [{cap_deg: 90}, {band_deg: 10}]`).
    changes = ([{vary: v} for v in values] if vary else
               [dict(c) for c in (sweep.get("points") or [{}])])
    min_k = max(get_method(a).min_samples for a in out["algorithms"])
    checks = {"K": (lambda k: k >= min_k and k == int(k),
                    f"an integer >= {min_k} (the largest minimum of the chosen methods)"),
              "sigma": (lambda s: s >= 0, ">= 0"), "beta": (lambda b: b >= 0, ">= 0"),
              "gamma": (lambda g: g >= 0, ">= 0"),
              "cap_deg": (lambda c: 0 < c <= 180, "in (0, 180] degrees"),
              "band_deg": (lambda b: 0 < b <= 90, "in (0, 90] degrees")}
    for key in POINT_COLUMNS:
        if key in nominal:
            ok, expected = checks[key]
            _number(nominal[key], f"nominal.{key}", ok, expected)
    for change in changes:
        for key, v in change.items():
            if key not in checks:
                raise UsageError(f"sweep point sets {key!r}; a point has "
                                 f"{', '.join(POINT_COLUMNS)}")
            _number(v, f"sweep value {key}", *checks[key])
    base = Point(int(nominal.K), float(nominal.sigma), float(nominal.beta),
                 float(nominal.gamma), lo, hi)
    out["points"] = [point_with(base, c) for c in changes]
    options = OmegaConf.to_container(cfg.options, resolve=True) or {}
    if not isinstance(options, dict):
        raise UsageError("options must map method names to option dicts, e.g. "
                         "+options.magical.max_iter=100")
    for name, opts in options.items():
        spec = get_method(name) if name in out["algorithms"] else None
        if spec is None:
            raise UsageError(f"options given for {name!r}, which is not among the selected "
                             f"algorithms ({', '.join(out['algorithms'])})")
        bad = sorted(set(opts or {}) - set(spec.option_names()))
        if bad:
            raise UsageError(f"unknown option(s) {', '.join(bad)} for {name}; it accepts: "
                             f"{', '.join(spec.option_names()) or 'no options'}")
    out["options"] = {k: dict(v or {}) for k, v in options.items()}
    out["results_dir"] = Path(str(cfg.results_dir))
    out["name"] = str(sweep.name)
    return out


def run(cfg: DictConfig) -> int:
    """Run the configured sweep, then write its tables."""
    from magbench.engine.sweep import run_study
    from magbench.report import write_sweep_tables
    from magbench.studies.review import ReviewStudy, read_trials

    if cfg.sweep.get("kind") == "gyro":
        from magbench.gyro_sweep import run_gyro_command

        return run_gyro_command(cfg)
    if cfg.sweep.get("kind") == "real":
        from magbench.real import run_real

        return run_real(cfg)
    if cfg.sweep.get("kind") == "wushi":
        from magbench.wushi_study import run_wushi

        return run_wushi(cfg)
    values = validate(cfg)
    spec = ReviewStudy(values["name"], values["points"], values["trials"], values["seed"],
                       values["algorithms"], values["options"], values["delta"],
                       values["call_timeout_s"], tuple(cfg.plugins or ()))
    out_dir = values["results_dir"] / spec.name
    run_study(spec, out_dir, n_jobs=values["n_jobs"], chunk_size=values["chunk_size"],
              backend=cfg.backend, scheduler_address=cfg.scheduler_address,
              progress=bool(cfg.progress), config=OmegaConf.to_container(cfg, resolve=True))
    summary = spec.summarize(out_dir)
    trials = read_trials(out_dir / "trials.csv")
    write_sweep_tables(spec.name, summary, out_dir, delta=spec.delta)
    n_bad = int((~trials["ok"].astype(bool)).sum())
    print(f"sweep {spec.name}: {len(trials)} rows ({n_bad} not ok) -> {out_dir}/trials.csv, "
          "summary.csv")
    return 0


def bench(cfg: DictConfig) -> int:
    """Time every method (``make bench``); writes ``<results_dir>/bench/``."""
    from magbench.bench import run_bench

    names = selected_algorithms(cfg)
    folder = run_bench(Path(str(cfg.results_dir)), names,
                       progress=(lambda line: print(line, file=sys.stderr)) if cfg.progress
                       else None)
    print(f"benchmark written to {folder}/ (calls.csv, scaling.png, peers.csv, parallel.csv, "
          "bench.md)")
    return 0


def calibrate_command(cfg: DictConfig) -> int:
    """Calibrate a user's recording (``python -m magbench calibrate file=PATH``)."""
    from magbench.calibrate_cmd import run_calibrate

    return run_calibrate(cfg)


def report(cfg: DictConfig) -> int:
    """Regenerate the figures and ``<results_dir>/report.md`` from the CSV files."""
    from magbench.report import write_report

    path = write_report(Path(str(cfg.results_dir)))
    print(f"report written to {path} (figures regenerated beside each sweep's CSV files)")
    return 0


COMMANDS = {"run": run, "bench": bench, "report": report, "calibrate": calibrate_command}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m magbench`` and the ``magbench`` script."""
    from magbench.engine.sweep import FolderBusy

    args = list(sys.argv[1:] if argv is None else argv)
    command = args.pop(0) if args and args[0] in COMMANDS else "run"
    if args and args[0] in ("-h", "--help", "help"):
        print(__doc__.strip())
        return 0
    try:
        return COMMANDS[command](compose_config(args))
    except UsageError as exc:
        print(f"magbench: error: {exc}", file=sys.stderr)
        return 2
    except FolderBusy as exc:
        print(f"magbench: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("magbench: interrupted; finished chunks are kept and a rerun completes the rest",
              file=sys.stderr)
        return 130
