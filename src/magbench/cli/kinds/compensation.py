"""The compensation sweep (static against compensated calibration under a current-proportional
disturbance, :mod:`magbench.studies.compensation`): a kind."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from magbench.cli.config import (
    Key,
    check_options,
    check_trials,
    field_default,
    is_list_of,
    nominal_point,
    number,
    selected_algorithms,
)
from magbench.cli.kinds import Kind, register_kind
from magbench.core.files import write_text_atomic
from magbench.studies.compensation import CompensationStudy


def build(cfg: DictConfig, common: dict, values: dict) -> CompensationStudy:
    """Disturbance strengths x ``trials`` manoeuvres, every selected method three ways."""
    algorithms = selected_algorithms(cfg)
    nominal = nominal_point(cfg, 10)
    return CompensationStudy(
        strengths=values["strengths"], trials=check_trials(cfg, "sweep compensation"),
        seed=common["seed"], algorithms=algorithms, options=check_options(cfg, algorithms),
        rate_hz=values["rate_hz"], duration_s=values["duration_s"], sigma=nominal.sigma,
        beta=nominal.beta, gamma=nominal.gamma, alpha=(nominal.alpha_low, nominal.alpha_high),
        delta=common["delta"], call_timeout_s=common["call_timeout_s"],
        plugins=common["plugins"], name=str(cfg.sweep.name))


def finish(study: CompensationStudy, out_dir: Path, common: dict) -> None:
    study.summarize(out_dir)


def figures(name: str, out_dir: Path) -> list[Path]:
    from magbench.figures.compensation import write_compensation_figures

    return write_compensation_figures(out_dir)


def section(out_dir: Path) -> None:
    from magbench.report.compensation import compensation_report_section

    write_text_atomic(compensation_report_section(out_dir.parent), out_dir / "section.md")


def report(results_dir: Path) -> str:
    from magbench.report.compensation import compensation_report_section

    return compensation_report_section(results_dir)


def _d(name: str) -> object:
    return field_default(CompensationStudy, name)


KIND = register_kind(Kind(
    name="compensation",
    what="static against compensated (y = T m + h + C u) calibration, disturbance strength",
    keys=(
        Key("strengths", [0.0, 0.01, 0.03, 0.1, 0.3], "|C| at full current, field = 1",
            is_list_of(number(lambda s: 0 <= s <= 10, "in [0, 10]"))),
        Key("rate_hz", _d("rate_hz"), "sample rate of the manoeuvre (Hz)",
            number(lambda r: 0 < r <= 10_000, "in (0, 10000] Hz")),
        Key("duration_s", _d("duration_s"), "manoeuvre length (s); K = rate_hz x duration_s",
            number(lambda d: 0 < d <= 3600, "in (0, 3600] s")),
    ),
    build=build, finish=finish, figures=figures, section=section, report=report))
