"""Real recordings (the review's section 10.2, Figure 6): a kind."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from omegaconf import DictConfig

from magbench.cli.config import (
    Key,
    UsageError,
    check_options,
    field_default,
    integer,
    number,
    one_or_more_of,
    plain,
    selected_algorithms,
)
from magbench.cli.kinds import Kind, register_kind
from magbench.core.files import write_text_atomic
from magbench.pipeline.fitting import PREPROCESSING
from magbench.studies.real import RealStudy


def recordings(cfg: DictConfig, datasets: object, sweep: str) -> tuple[str, list[str]]:
    """``data_dir`` and the recordings of ``sweep.datasets`` ('all' or names) in it, for a
    kind that reads every recording once (``trials`` refused); exit 2 on a bad value."""
    from magbench.sources.recordings import data_dir, list_recordings

    if cfg.get("trials") is not None:
        raise UsageError(f"trials does not apply to sweep={sweep} (every recording is used "
                         "once, deterministically); drop trials=")
    try:
        root = data_dir(cfg.get("data_dir"))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    known = list_recordings(root)
    chosen = known if datasets == "all" else [datasets] if isinstance(datasets, str) \
        else list(datasets)
    unknown = [d for d in chosen if d not in known]
    if unknown or not chosen:
        raise UsageError(f"unknown recording(s) {', '.join(map(str, unknown)) or '(none)'} in "
                         f"{root}; expected 'all' or a list from: {', '.join(known)}")
    return str(root), chosen


def build(cfg: DictConfig, common: dict, values: dict) -> RealStudy:
    """The real-data sweep over the recordings in ``data_dir`` (one fit per recording)."""
    root, chosen = recordings(cfg, values["datasets"], "real")
    algorithms = selected_algorithms(cfg, include_gyro=True)
    return RealStudy(root, chosen, algorithms, tuple(values["preprocess"]),
                     values["max_samples"], check_options(cfg, algorithms), common["seed"],
                     common["call_timeout_s"], values["coverage_ratio"],
                     values["sphere_factor"], common["plugins"], str(cfg.sweep.name))


def finish(study: RealStudy, out_dir: Path, common: dict) -> None:
    study.summarize(out_dir)


def figures(name: str, out_dir: Path) -> list[Path]:
    from magbench.figures.real import figure6, figure6_recordings
    from magbench.figures.style import save_figure

    if not (out_dir / "fig6_real.csv").exists():
        return []
    per_method = pd.read_csv(out_dir / "fig6_real.csv")
    per_recording = pd.read_csv(out_dir / "real_summary.csv")
    return [save_figure(figure6(per_method, per_recording), out_dir / "fig6_real.png"),
            save_figure(figure6_recordings(per_method, per_recording),
                        out_dir / "fig6_real_recordings.png")]


def section(out_dir: Path) -> None:
    from magbench.report.real import real_report_section

    write_text_atomic(real_report_section(out_dir.parent, "fig6_real.png") + "\n",
                      out_dir / "real.md")


def report(results_dir: Path) -> str:
    from magbench.report.real import real_report_section

    return real_report_section(results_dir)


KIND = register_kind(Kind(
    name="real", what="every method on real recordings (data_dir), Figure 6", keys=(
        Key("datasets", "all", "'all' or a list of recording folder names",
            lambda v, what: plain(v)),
        Key("max_samples", field_default(RealStudy, "max_samples"), "longer recordings are "
            "thinned to every ceil(n/max_samples)-th sample", integer(8, 10_000_000)),
        Key("preprocess", list(field_default(RealStudy, "preprocess")), "scale: divide by the "
            "mean norm (the review's); centre: also subtract the sphere-fit centre",
            one_or_more_of(PREPROCESSING)),
        Key("coverage_ratio", field_default(RealStudy, "coverage_ratio"), "meaningful fits "
            "keep at least this share of the sphere fit's coverage",
            number(lambda r: 0 <= r <= 1, "in [0, 1]")),
        Key("sphere_factor", field_default(RealStudy, "sphere_factor"), "meaningful fits have "
            "J_r at most this times the sphere fit's", number(lambda f: 0 < f <= 1e6, "> 0")),
    ),
    build=build, finish=finish, figures=figures, section=section, report=report,
    needs_data=True))
