"""Study kinds, registered as methods are: the command line iterates over this registry.

A kind (the review's sweeps, gyro, real, Wu-Shi, ...) is declared once, in one module of this
package (or in a plugin or test module), as a :class:`Kind`: its ``sweep.*`` keys with their
defaults and checks, how to build its study from the checked configuration, what to compute
once the trials are done, its figures and its report text. ``run``, ``report``, ``reproduce``,
the configuration check and the help text ask the registry; nothing outside a kind's own
modules tests which kind it is.

The registry lives in ``cli``, the one layer that may import studies, figures and report
together, so that a kind's parts stay in their own layers and one declaration joins them.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from omegaconf import DictConfig

from magbench.cli.config import (
    Key,
    UsageError,
    check_common,
    config_dir,
    did_you_mean,
    read_keys,
)

__all__ = ["BASE_KEYS", "Kind", "get_kind", "kind_names", "kind_of_sweep", "register_kind",
           "study_for", "unregister_kind"]

#: Keys every sweep section has: its folder name, its kind, and a varied parameter.
BASE_KEYS = ("name", "kind", "vary", "values")

#: The kinds shipped with magbench, in the order their report sections appear.
_BUILTIN = ("review", "real", "generalisation", "wushi", "gyro", "heading", "compensation")


def _no_figures(name: str, out_dir: Path) -> list[Path]:
    return []


@dataclass(frozen=True)
class Kind:
    """One study kind.

    Attributes
    ----------
    name : str
        The value of ``sweep.kind`` that selects it.
    what : str
        One line for the help text.
    keys : tuple of Key
        The ``sweep.*`` keys it reads besides :data:`BASE_KEYS`, with defaults and checks.
    build : callable
        ``build(cfg, common, values) -> Study``: the study from the composed configuration, the
        checked common values (:func:`magbench.cli.config.check_common`) and the checked
        ``sweep.*`` values.
    finish : callable
        ``finish(study, out_dir, common)``: everything computed once the trials are written
        (summaries, tables, timing passes).
    figures : callable
        ``figures(name, out_dir) -> list of Path``: its figures, from its CSV files only.
    section : callable or None
        ``section(out_dir)``: writes the sweep's own Markdown beside its files.
    report : callable or None
        ``report(results_dir) -> str``: its part of ``report.md`` ('' when it has no results).
    needs_data : bool
        It reads recordings from ``data_dir``; ``reproduce`` skips it when none is set.
    timed : bool
        It has a timing protocol that ``bench timing_check=true`` can repeat.
    """

    name: str
    what: str
    keys: tuple[Key, ...]
    build: Callable[[DictConfig, dict, dict], object]
    finish: Callable[[object, Path, dict], None]
    figures: Callable[[str, Path], list[Path]] = _no_figures
    section: Callable[[Path], None] | None = None
    report: Callable[[Path], str] | None = None
    needs_data: bool = False
    timed: bool = False

    def key_names(self) -> tuple[str, ...]:
        return tuple(k.name for k in self.keys)


_KINDS: dict[str, Kind] = {}
_loaded = False


def register_kind(kind: Kind) -> Kind:
    """Add ``kind`` to the registry (replacing one of the same name); returns it."""
    _KINDS[kind.name] = kind
    return kind


def unregister_kind(name: str) -> None:
    """Remove a kind (a test's toy kind, say); unknown names are ignored."""
    _KINDS.pop(name, None)


def _load() -> None:
    global _loaded
    if not _loaded:
        _loaded = True
        for name in _BUILTIN:
            importlib.import_module(f"magbench.cli.kinds.{name}")


def kind_names() -> list[str]:
    """Every registered kind, built-in ones first, in report order."""
    _load()
    return list(_KINDS)


def get_kind(name: str) -> Kind:
    """The kind registered as ``name``; :class:`UsageError` with a suggestion otherwise."""
    _load()
    if name not in _KINDS:
        close = did_you_mean(str(name), _KINDS)
        raise UsageError(f"sweep.kind must be one of {', '.join(_KINDS)}, got {name!r}"
                         + (f" (did you mean {close!r}?)" if close else ""))
    return _KINDS[name]


def kind_of(cfg: DictConfig) -> Kind:
    """The kind of the composed configuration's sweep (``review`` when it names none)."""
    return get_kind(str(cfg.sweep.get("kind", "review")))


def kind_of_sweep(name: str) -> Kind | None:
    """The kind of ``conf/sweep/<name>.yaml`` (read without Hydra), or None if there is none."""
    import yaml

    path = config_dir() / "sweep" / f"{name}.yaml"
    if not path.exists():
        return None
    data = yaml.safe_load(path.read_text()) or {}
    section = data.get("sweep", data) if isinstance(data.get("sweep"), dict) else data
    return get_kind(str(section.get("kind", "review")))


def study_for(cfg: DictConfig) -> tuple[object, dict]:
    """The study and common values of the sweep chosen by ``sweep=``, every value checked."""
    kind = kind_of(cfg)
    allowed = BASE_KEYS + kind.key_names()
    unknown = [str(k) for k in cfg.sweep if k not in allowed]
    if unknown:
        close = did_you_mean(unknown[0], allowed[2:])
        hint = (" (the number of trials is the top-level key: trials=N)"
                if "trials" in unknown else f" (did you mean sweep.{close}?)" if close else "")
        raise UsageError(f"unknown key(s) sweep.{', sweep.'.join(unknown)} for a {kind.name} "
                         f"sweep{hint}; it reads sweep."
                         f"{', sweep.'.join(allowed[2:]) or '(no keys)'}")
    common = check_common(cfg)
    values = read_keys(cfg.sweep, kind.keys, "sweep.")
    return kind.build(cfg, common, values), common
