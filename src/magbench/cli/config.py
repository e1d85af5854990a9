"""The one configuration check: every command's composed config is checked here, once.

A bad value gives :class:`UsageError`, printed as one line naming the key and what is expected,
with exit status 2, before any result is touched. The checks of the keys every sweep shares are
here; each study kind declares its own ``sweep.*`` keys as :class:`Key` s (default, meaning,
check) in its module of :mod:`magbench.cli.kinds`, read by :func:`read_keys`; ``calibrate`` uses
the same checks for its keys.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import difflib
import math
import os
import re
import tempfile
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from omegaconf import DictConfig, OmegaConf

from magbench.core.geomagnetic import Site, parse_date, parse_location
from magbench.core.units import Units, parse_field, parse_units
from magbench.engine.plugins import load_plugins
from magbench.methods.registry import get_method, methods

if TYPE_CHECKING:
    from magbench.sources.synthetic import Point

__all__ = [
    "Key",
    "UsageError",
    "base_config",
    "check_columns",
    "check_common",
    "check_compensate",
    "check_field_strength",
    "check_flag",
    "check_instance",
    "check_integer",
    "check_number",
    "check_options",
    "check_override_keys",
    "check_scale",
    "check_site",
    "check_trials",
    "check_units",
    "compose_config",
    "config_dir",
    "did_you_mean",
    "field_default",
    "integer",
    "is_list_of",
    "nominal_point",
    "number",
    "one_or_more_of",
    "overwrite_wanted",
    "plain",
    "plain_override",
    "point_checks",
    "read_keys",
    "selected_algorithms",
    "writable_folder",
]


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


def did_you_mean(word: str, choices: Sequence[str] | dict) -> str | None:
    """The closest of ``choices`` to a misspelt ``word``, or None when none is close."""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return close[0] if close else None


#: One YAML load at a time: capture calibrates from a second thread, and a load that another
#: thread's interleaves with must not hand back a partial configuration.
_YAML_LOCK = threading.Lock()


def _load_yaml(text: str) -> dict:
    """A configuration file's text as plain data (LibYAML's loader where PyYAML has it)."""
    import yaml

    with _YAML_LOCK:
        return yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader)) or {}


def base_config() -> dict:
    """``conf/config.yaml`` as plain data, without its defaults list."""
    data = _load_yaml((config_dir() / "config.yaml").read_text())
    data.pop("defaults", None)
    return data


#: Sections whose keys are open: a sweep's keys are checked by its kind once composed, a
#: method's options by :func:`check_options`, Hydra's own by Hydra.
_OPEN_SECTIONS = ("sweep", "options", "hydra")


def check_override_keys(overrides: Sequence[str]) -> None:
    """Refuse an override of a key the configuration does not have, with a suggestion.

    Hydra would advise ``+key=value``, which then runs with the misspelt key ignored.
    """
    base = base_config()
    for override in overrides:
        path = override.lstrip("+~").split("=", 1)[0].split(".")
        if path[0] in _OPEN_SECTIONS:
            continue
        node: object = base
        for depth, key in enumerate(path):
            if not isinstance(node, dict):
                break
            if key not in node:
                where = ".".join(path[:depth])
                known = [f"{where}.{k}" if where else k for k in node]
                full = ".".join(path[:depth + 1])
                close = did_you_mean(full, known)
                hint = f"; did you mean {close!r}?" if close else ""
                raise UsageError(f"unknown key {full!r}{hint} (python -m magbench COMMAND "
                                 "--help lists the keys a command reads)")
            node = node[key]


def compose_config(overrides: Sequence[str]) -> DictConfig:
    """Compose ``conf/config.yaml`` with Hydra overrides (``key=value`` strings), after
    :func:`check_override_keys`.

    Overrides of plain values (:func:`plain_override`, parsed by Hydra's own parser) are
    applied to the configuration files directly, which gives the config Hydra's compose API
    would give without Hydra's config search and defaults machinery; any other override
    (another sweep, nested values, interpolations, sweeps of values, ``~key``) is composed by
    Hydra, whose messages name what is wrong.
    """
    check_override_keys(overrides)
    cfg = _compose_plain(overrides)
    if cfg is not None:
        return cfg
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


#: Top-level keys whose overrides are left to Hydra (a sweep's file, Hydra's own settings).
_HYDRA_KEYS = ("sweep", "hydra")


def _flat_value(value: object) -> bool:
    """Whether a parsed override value is a scalar or a flat list of scalars, without an
    interpolation (which Hydra's compose resolves against the config)."""
    if isinstance(value, list):
        return all(not isinstance(v, list | dict) and _flat_value(v) for v in value)
    if isinstance(value, str):
        return "${" not in value
    return value is None or isinstance(value, bool | int | float)


def plain_override(override: str) -> tuple[str, bool, object]:
    """``(key, add, value)`` of a ``[++]key=value`` override whose value is a plain scalar or a
    flat list of them (``[mx,my,mz]``), parsed and typed by Hydra's own override parser;
    ``add``: the ``++`` prefix.

    Raises
    ------
    ValueError
        Any other override, which is left to Hydra's compose: one that does not parse, a
        package, ``+key`` or ``~key``, a sweep of values (a comma outside brackets), a nested,
        dict or interpolated value, or a key of another sweep or of Hydra's settings.
    """
    # Imported here, not at load: ``--help`` and the commands without overrides skip it.
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.core.override_parser.types import OverrideType, ValueType
    from hydra.errors import HydraException

    try:
        parsed = OverridesParser.create().parse_override(override)
    except HydraException:
        raise ValueError(f"not a plain override: {override!r}") from None
    key = parsed.key_or_group
    if (parsed.package is not None or parsed.value_type is not ValueType.ELEMENT
            or parsed.type not in (OverrideType.CHANGE, OverrideType.FORCE_ADD)
            or key.split(".")[0] in _HYDRA_KEYS or not _flat_value(parsed.value())):
        raise ValueError(f"not a plain override: {override!r}")
    return key, parsed.type is OverrideType.FORCE_ADD, parsed.value()


def _compose_plain(overrides: Sequence[str]) -> DictConfig | None:
    """The composed config when every override is plain (:func:`plain_override`) and sets a
    key the configuration has (or adds one under ``++``) without replacing a section; None
    otherwise (Hydra composes it)."""
    data = _load_yaml((config_dir() / "config.yaml").read_text())
    for group in data.pop("defaults", None) or []:
        # _self_ first, then the default sweep's file as the sweep section, as Hydra merges
        # them; a sweep file with a package or defaults of its own is left to Hydra.
        if group == "_self_":
            continue
        if not isinstance(group, dict) or list(group) != ["sweep"]:
            return None
        text = (config_dir() / "sweep" / f"{group['sweep']}.yaml").read_text()
        data["sweep"] = _load_yaml(text)
        if "@package" in text or "defaults" in data["sweep"]:
            return None
    for override in overrides:
        try:
            key, add, value = plain_override(override)
        except ValueError:
            return None
        *parents, last = key.split(".")
        node = data
        for part in parents:
            if part not in node and add:
                node[part] = {}
            node = node.get(part)
            if not isinstance(node, dict):
                return None
        if (last not in node and not add) or isinstance(node.get(last), dict):
            return None
        node[last] = value
    cfg = OmegaConf.create(data)
    OmegaConf.set_struct(cfg, True)
    return cfg


def check_integer(value: object, what: str, low: int, high: int | None = None) -> int:
    """``value`` if it is an integer in [``low``, ``high``]; otherwise a :class:`UsageError`
    naming it."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise UsageError(f"{what} must be an integer >= {low}, got {value!r}")
    if high is not None and value > high:
        raise UsageError(f"{what} must be an integer <= {high}, got {value!r}")
    return value


#: What ``compensate`` may list: the regressors of the time-varying terms.
COMPENSATE = ("current", "throttle", "temperature")


def check_compensate(cfg: DictConfig) -> list[str] | None:
    """The ``compensate`` key of calibrate: None for ``auto`` (the recording's current or
    throttle and temperature), [] for ``none``, else the listed regressors."""
    value = cfg.get("compensate", "auto")
    if value in ("auto", None):
        return None
    if value == "none":
        return []
    names = list(OmegaConf.to_container(value)) if OmegaConf.is_list(value) else [value]
    bad = [n for n in names if n not in COMPENSATE]
    if bad or not names:
        raise UsageError(f"compensate must be auto, none or a list of {', '.join(COMPENSATE)}, "
                         f"e.g. compensate=[current,temperature], got {value!r}")
    return [str(n) for n in names]


#: The largest dataset a synthetic point may ask for: every trial holds K x 3 samples and a few
#: copies per method; beyond this a worker runs out of memory rather than failing in one line.
MAX_K = 1_000_000

#: The largest sigma, beta, gamma or alpha (field units, the field has norm 1): larger values
#: overflow in squares of the samples and no calibration problem is that distorted.
MAX_DISTORTION = 1000.0

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


@dataclass(frozen=True)
class Key:
    """One ``sweep.*`` key of a study kind: its default, what it means, and its check.

    ``check(value, what)`` returns the checked value (converted if need be) or raises
    :class:`UsageError` naming ``what``, the full key.
    """

    name: str
    default: object
    meaning: str
    check: Callable[[object, str], object]


def read_keys(section: DictConfig, keys: Sequence[Key], prefix: str) -> dict:
    """``name -> checked value`` of ``keys`` in ``section`` (each key's default when absent)."""
    return {k.name: k.check(plain(section.get(k.name, k.default)), f"{prefix}{k.name}")
            for k in keys}


def field_default(cls: type, name: str) -> object:
    """The default of the dataclass field ``name`` of ``cls`` (the study's single source)."""
    for f in dataclasses.fields(cls):
        if f.name == name:
            if f.default is not dataclasses.MISSING:
                return f.default
            if f.default_factory is not dataclasses.MISSING:
                return f.default_factory()
    raise KeyError(f"{cls.__name__} has no field {name!r} with a default")


def number(ok: Callable[[float], bool], expected: str) -> Callable[[object, str], float]:
    """A :class:`Key` check: a finite number for which ``ok`` holds."""
    return lambda value, what: check_number(value, what, ok, expected)


def integer(low: int, high: int | None = None) -> Callable[[object, str], int]:
    """A :class:`Key` check: an integer in [``low``, ``high``]."""
    return lambda value, what: check_integer(value, what, low, high)


def is_list_of(check: Callable[[object, str], object]) -> Callable[[object, str], list]:
    """A :class:`Key` check: a non-empty list whose every item passes ``check``."""
    def check_list(value: object, what: str) -> list:
        value = plain(value)
        if not isinstance(value, list | tuple) or not value:
            raise UsageError(f"{what} must be a non-empty list, e.g. {what}=[1,2], "
                             f"got {value!r}")
        return [check(v, f"{what}[{i}]") for i, v in enumerate(value)]
    return check_list


def one_or_more_of(choices: Sequence[str]) -> Callable[[object, str], list[str]]:
    """A :class:`Key` check: one of ``choices`` or a non-empty list of them (as a list)."""
    def check(value: object, what: str) -> list[str]:
        value = plain(value)
        value = [value] if isinstance(value, str) else list(value or [])
        if not value or any(v not in choices for v in value):
            raise UsageError(f"{what} must be a list from {', '.join(choices)}, got {value}")
        return value
    return check


def plain(node: object, what: str = "") -> object:
    """``node`` as plain Python data (lists, dicts) if it is an OmegaConf node."""
    return OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node


def selected_algorithms(cfg: DictConfig, include_gyro: bool = False,
                        include_accel: bool = False) -> list[str]:
    """The method names of ``algorithms=`` ('all' or a list), checked against the registry.

    'all' means every magnetometer-only method, plus the gyro-aided ones with
    ``include_gyro`` (for data that have angular rate: the gyro sweep, real recordings) and
    the alignment methods, which need an accelerometer, with ``include_accel`` (the heading
    study, whose data have one); otherwise those only when named.
    """
    known = methods()
    chosen = plain(cfg.algorithms)
    if chosen == "all":
        def wanted(spec) -> bool:
            return ((not spec.needs_gyro or include_gyro)
                    and (not spec.needs_accel or include_accel))
        return [m for m in known if wanted(get_method(m))]
    chosen = [chosen] if isinstance(chosen, str) else list(chosen or [])
    unknown = [a for a in chosen if a not in known]
    if unknown or not chosen:
        raise UsageError(f"unknown algorithm(s) {', '.join(map(str, unknown)) or '(none given)'}"
                         f"; expected 'all' or a list from: {', '.join(known)}")
    twice = sorted({a for a in chosen if chosen.count(a) > 1})
    if twice:
        raise UsageError(f"algorithms lists {', '.join(twice)} more than once; name each "
                         "method once")
    gyro = [a for a in chosen if get_method(a).needs_gyro]
    if gyro and not include_gyro:
        raise UsageError(f"{', '.join(gyro)} need(s) gyro data, which this sweep does not "
                         "simulate; run them with sweep=gyro or sweep=real")
    return chosen


def check_options(cfg: DictConfig, algorithms: Sequence[str]) -> dict[str, dict]:
    """``options.<method>.<option>`` values, each naming a selected method and one of its
    options (:meth:`magbench.methods.registry.Method.option_names`)."""
    options = plain(cfg.get("options")) or {}
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
        defaults = option_defaults(name)
        for option, value in opts.items():
            check_option_value(value, defaults.get(option), f"options.{name}.{option}")
        out[name] = dict(opts)
    return out


def option_defaults(name: str) -> dict[str, object]:
    """``option -> default`` of the registered method ``name`` (options without one omitted)."""
    import inspect

    params = inspect.signature(get_method(name).fit).parameters
    return {o: params[o].default for o in get_method(name).option_names()
            if params[o].default is not inspect.Parameter.empty}


def check_option_value(value: object, default: object, what: str) -> object:
    """``value`` if it has the type of the option's ``default`` (an integer option takes a
    non-negative integer, a float option a finite number, a flag true or false)."""
    if isinstance(default, bool):
        return check_flag(value, what)
    if isinstance(default, int):
        return check_integer(value, what, 0)
    if isinstance(default, float):
        return check_number(value, what, lambda v: True, "(a finite number)")
    if isinstance(default, str) and not isinstance(value, str):
        raise UsageError(f"{what} must be a name like its default {default!r}, got {value!r}")
    return value


#: Most worker processes per CPU that n_jobs may ask for.
JOBS_PER_CPU = 4


def check_common(cfg: DictConfig) -> dict:
    """Keys every sweep shares: seed, n_jobs, chunk_size, delta, backend, call_timeout_s,
    plugins (imported here, so their methods are known to the checks that follow)."""
    plugins = _plugins(cfg)
    n_jobs = cfg.n_jobs
    if isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs == 0:
        raise UsageError(f"n_jobs must be a non-zero integer (-1 = every core), got {n_jobs!r}")
    most = JOBS_PER_CPU * (os.cpu_count() or 1)
    if abs(n_jobs) > most:      # each worker is a process: 10^5 of them would swamp the machine
        raise UsageError(f"n_jobs must be at most {most} ({JOBS_PER_CPU} per CPU of this "
                         f"machine's {os.cpu_count() or 1}; -1 = every core), got {n_jobs}")
    if cfg.backend not in ("loky", "dask"):
        raise UsageError(f"backend must be 'loky' or 'dask', got {cfg.backend!r}")
    timeout = cfg.call_timeout_s
    return {
        "seed": check_integer(cfg.seed, "seed", 0),
        "n_jobs": n_jobs,
        "chunk_size": check_integer(cfg.chunk_size, "chunk_size", 1),
        "delta": check_number(cfg.delta, "delta", lambda d: 0 < d < 1, "in (0, 1)"),
        "backend": str(cfg.backend),
        "scheduler_address": _scheduler_address(cfg.get("scheduler_address")),
        "call_timeout_s": None if timeout is None else check_number(
            timeout, "call_timeout_s", lambda t: 0 < t <= MAX_TIMEOUT_S,
            f"in (0, {MAX_TIMEOUT_S:g}] seconds (or null for no limit)"),
        "plugins": tuple(plugins),
        "progress": check_flag(cfg.progress, "progress"),
        "overwrite": check_flag(cfg.get("overwrite", False), "overwrite"),
        "results_dir": _results_dir(cfg),
    }


#: The longest time limit of one call (a week): beyond it the deadline overflows the clock.
MAX_TIMEOUT_S = 604_800.0


def _plugins(cfg: DictConfig) -> list[str]:
    """The ``plugins`` list, each module imported: any failure to import is one line."""
    plugins = plain(cfg.get("plugins")) or []
    if not isinstance(plugins, list) or not all(isinstance(p, str) and p for p in plugins):
        raise UsageError(f"plugins must be a list of module names, e.g. plugins=[mylab.method], "
                         f"got {plugins!r}")
    for name in plugins:
        if name.startswith("."):
            raise UsageError(f"plugin module {name!r} is relative; give its full name, e.g. "
                             "mylab.method")
        try:
            load_plugins([name])
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        except Exception as exc:   # a plugin's own code failing at import, of any kind
            text = " ".join(str(exc).split())
            raise UsageError(f"plugin module {name!r} failed to import: "
                             f"{type(exc).__name__}: {text}") from None
    return plugins


def _scheduler_address(value: object) -> str | None:
    """A Dask scheduler address such as tcp://10.0.0.5:8786, or None."""
    if value is None:
        return None
    if not isinstance(value, str) or not re.fullmatch(
            r"((tcp|tls|ucx|ws|wss)://)?[^\s:/]+:\d{1,5}", value):
        raise UsageError(f"scheduler_address must be a Dask scheduler address such as "
                         f"tcp://10.0.0.5:8786, or null for a local cluster, got {value!r}")
    return value


def picture_wanted(cfg: DictConfig) -> bool:
    """``calibrate``'s ``picture`` key: whether to draw ``calibration.png``."""
    return check_flag(cfg.get("picture", True), "picture")


def check_flag(value: object, key: str) -> bool:
    """``value`` if it is a boolean (a :class:`Key` check too), else exit 2 saying so."""
    if not isinstance(value, bool):
        raise UsageError(f"{key} must be true or false, got {value!r}")
    return value


def _results_dir(cfg: DictConfig) -> Path:
    if not isinstance(cfg.get("results_dir"), str) or not cfg.results_dir:
        raise UsageError(f"results_dir must be a folder path, e.g. results_dir=results, got "
                         f"{cfg.get('results_dir')!r}")
    path = Path(str(cfg.results_dir)).expanduser()
    _no_file_in_the_way(path, "results_dir")
    return path


#: The trials of one ``bench scale=[...]`` size: below the smallest the fixed costs hide the
#: growth; above the largest the run's trials.csv outgrows a disk's free space.
SCALE_RANGE = (1_000, 10_000_000)


def check_scale(cfg: DictConfig) -> list[int] | None:
    """The bench's ``scale`` key: a non-empty list of trial counts in :data:`SCALE_RANGE`, or
    None (no scale run)."""
    value = plain(cfg.get("scale"))
    if value is None:
        return None
    low, high = SCALE_RANGE
    if not isinstance(value, list) or not value:
        raise UsageError(f"scale must be a list of trial counts, e.g. scale=[10000,30000], or "
                         f"null, got {value!r}")
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, int) or not low <= v <= high:
            raise UsageError(f"scale[{i}] must be an integer in [{low}, {high}], got {v!r}")
    return value


def check_trials(cfg: DictConfig, what: str) -> int:
    """The top-level ``trials``, required by ``what``."""
    if cfg.get("trials") is None:
        raise UsageError(f"trials must be set for {what}")
    return check_integer(cfg.trials, "trials", 1, MAX_TRIALS)


def nominal_point(cfg: DictConfig, min_k: int) -> Point:
    """The checked nominal point of eq. (80) (``nominal.*``)."""
    from magbench.sources.synthetic import Point
    from magbench.studies.review import POINT_COLUMNS

    nominal = cfg.nominal
    alpha = plain(nominal.alpha)
    if not isinstance(alpha, list) or len(alpha) != 2:
        raise UsageError(f"nominal.alpha must be a list [low, high], got {alpha!r}")
    lo = check_number(alpha[0], "nominal.alpha[0]", lambda a: 0 < a <= MAX_DISTORTION,
                      f"in (0, {MAX_DISTORTION}]")
    hi = check_number(alpha[1], "nominal.alpha[1]", lambda a: lo <= a <= MAX_DISTORTION,
                      f"in [{lo}, {MAX_DISTORTION}]")
    for key in POINT_COLUMNS:
        if key in nominal:
            check_number(nominal[key], f"nominal.{key}", *point_checks(min_k)[key])
    return Point(int(nominal.K), float(nominal.sigma), float(nominal.beta),
                 float(nominal.gamma), lo, hi)


def point_checks(min_k: int) -> dict:
    """``key -> (ok, expected)`` for every parameter of a review point."""
    return {"K": (lambda k: min_k <= k <= MAX_K and k == int(k),
                  f"an integer in [{min_k}, {MAX_K}] (the low end is the largest minimum "
                  "of the chosen methods)"),
            "sigma": (lambda s: 0 <= s <= MAX_DISTORTION, f"in [0, {MAX_DISTORTION}]"),
            "beta": (lambda b: 0 <= b <= MAX_DISTORTION, f"in [0, {MAX_DISTORTION}]"),
            "gamma": (lambda g: 0 <= g <= MAX_DISTORTION, f"in [0, {MAX_DISTORTION}]"),
            "cap_deg": (lambda c: 0 < c <= 180, "in (0, 180] degrees"),
            "band_deg": (lambda b: 0 < b <= 90, "in (0, 90] degrees")}


def _no_file_in_the_way(path: Path, key: str) -> None:
    """Refuse a folder ``path`` that is a file or lies below one (the check of a folder that
    is not created yet: whether it can be written is tried by :func:`writable_folder`)."""
    for parent in [path, *path.parents]:
        if parent.exists() and not parent.is_dir():
            what = "is" if parent == path else f"cannot be created: {parent} is"
            raise UsageError(f"{key}={path} {what} a file; expected a folder")
        if parent.exists():
            return


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
    _no_file_in_the_way(path, key)
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
        return parse_units(plain(cfg.get("units")))
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def check_field_strength(cfg: DictConfig, units: Units) -> float | None:
    """``field_strength`` of calibrate: the expected field, in file units or with a unit
    (``48uT``), converted to file units; None when unset."""
    try:
        return parse_field(plain(cfg.get("field_strength")), units)
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def check_instance(cfg: DictConfig) -> str | None:
    """``instance``: the value of the sensor-instance column to keep (compared as text, so
    ``instance=1`` matches a cell ``1``); None when unset."""
    value = plain(cfg.get("instance"))
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, str | int | float):
        raise UsageError(f"instance must be one value of the file's instance column, e.g. "
                         f"instance=1, got {value!r}")
    return str(value)


def overwrite_wanted(cfg: DictConfig) -> bool:
    """``overwrite`` of calibrate (false when unset); checked against the folder under its
    lock (:func:`magbench.cli.outfolder.hold`)."""
    value = cfg.get("overwrite")
    return check_flag(value if value is not None else False, "overwrite")


def check_site(cfg: DictConfig) -> tuple[Site | None, dt.date | None]:
    """``location=lat,lon[,alt]`` and ``date=`` (calibrate's geomagnetic check), parsed.

    ``date`` without ``location`` is refused (it has nothing to check); ``location`` without
    ``date`` means today.

    Raises
    ------
    UsageError
        A malformed location or date, one line naming the expected form.
    """
    location, date = plain(cfg.get("location")), plain(cfg.get("date"))
    if location is None:
        if date is not None:
            raise UsageError("date= is used with location=lat,lon[,alt]; give both or neither")
        return None, None
    try:
        return parse_location(location), parse_date(date if date is not None else
                                                     dt.date.today())
    except ValueError as exc:
        raise UsageError(str(exc)) from None
