"""The gyro sweep (gyro-aided methods on simulated manoeuvres): a kind."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from omegaconf import DictConfig

from magbench.cli.config import (
    Key,
    UsageError,
    check_options,
    check_trials,
    field_default,
    is_list_of,
    nominal_point,
    number,
    plain,
    selected_algorithms,
)
from magbench.cli.kinds import Kind, register_kind
from magbench.core.files import write_text_atomic
from magbench.studies.gyro import DEFAULT_COVERAGES, GyroPoint, GyroStudy


def build(cfg: DictConfig, common: dict, values: dict):
    """The gyro sweep: coverages x gyro noise levels, ``trials`` manoeuvres each."""
    coverages = values["coverages"]
    chosen = list(values["coverage"] or coverages)
    unknown = [c for c in chosen if c not in coverages]
    if unknown:
        raise UsageError(f"unknown coverage(s) {', '.join(map(str, unknown))}; defined: "
                         f"{', '.join(coverages)}")
    algorithms = selected_algorithms(cfg, include_gyro=True)
    nominal = nominal_point(cfg, 4)
    return GyroStudy(
        points=[GyroPoint(c, g, nominal.sigma) for c in chosen for g in values["gyro_noise"]],
        trials=check_trials(cfg, "sweep gyro"), seed=common["seed"], algorithms=algorithms,
        options=check_options(cfg, algorithms), coverages=coverages,
        rate_hz=values["rate_hz"], duration_s=values["duration_s"], beta=nominal.beta,
        gamma=nominal.gamma, alpha=(nominal.alpha_low, nominal.alpha_high),
        gyro_bias_max=values["gyro_bias_max"], delta=common["delta"],
        call_timeout_s=common["call_timeout_s"], plugins=common["plugins"],
        name=str(cfg.sweep.name))


def finish(study, out_dir: Path, common: dict) -> None:
    study.summarize(out_dir)


def figures(name: str, out_dir: Path) -> list[Path]:
    from magbench.figures.gyro import write_gyro_figure

    if not (out_dir / "summary.csv").exists():
        return []
    return [write_gyro_figure(pd.read_csv(out_dir / "summary.csv"), out_dir)]


def section(out_dir: Path) -> None:
    from magbench.report.gyro import gyro_report_section

    write_text_atomic(gyro_report_section(out_dir.parent), out_dir / "section.md")


def report(results_dir: Path) -> str:
    from magbench.report.gyro import gyro_report_section

    return gyro_report_section(results_dir)


def _coverages(value: object, what: str) -> dict:
    value = plain(value)
    if not isinstance(value, dict) or not all(isinstance(v, dict) for v in value.values()):
        raise UsageError(f"{what} must map coverage names to simulator settings, e.g. "
                         f"{what}.wide={{motion: random, rate_rms: 0.8}}, got {value!r}")
    return value


def _d(name: str) -> object:
    return field_default(GyroStudy, name)


KIND = register_kind(Kind(
    name="gyro", what="gyro-aided and magnetometer-only methods on simulated manoeuvres",
    keys=(
        Key("rate_hz", _d("rate_hz"),
            "sample rate of magnetometer and gyro (Hz)",
            number(lambda r: 0 < r <= 10_000, "in (0, 10000] Hz")),
        Key("duration_s", _d("duration_s"),
            "manoeuvre length (s); K = rate_hz x duration_s",
            number(lambda d: 0 < d <= 3600, "in (0, 3600] s")),
        Key("gyro_bias_max", _d("gyro_bias_max"),
            "gyro bias components uniform in +-this (rad/s)",
            number(lambda b: 0 <= b <= 10, "in [0, 10] rad/s")),
        Key("gyro_noise", [0.0, 0.005, 0.03], "gyro white-noise std values (rad/s)",
            is_list_of(number(lambda x: 0 <= x <= 10, "in [0, 10] rad/s"))),
        Key("coverage", ["wide", "wu_shi", "low"], "the coverages run (names from sweep.coverages)",
            lambda v, what: list(plain(v) or [])),
        Key("coverages", DEFAULT_COVERAGES, "named coverages: keyword arguments of "
            "magbench.sources.trajectory.simulate", _coverages),
    ),
    build=build, finish=finish, figures=figures, section=section, report=report))
