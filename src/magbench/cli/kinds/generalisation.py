"""Generalisation on real recordings (fit on one part, score on the rest): a kind."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from magbench.cli.config import (
    Key,
    UsageError,
    check_flag,
    check_options,
    field_default,
    integer,
    one_or_more_of,
    plain,
)
from magbench.cli.kinds import Kind, register_kind
from magbench.cli.kinds.real import recordings
from magbench.core.files import write_text_atomic
from magbench.studies.generalisation import PROTOCOLS, GeneralisationStudy, fixed_methods


def build(cfg: DictConfig, common: dict, values: dict) -> GeneralisationStudy:
    """The study over the recordings in ``data_dir``, every protocol, every fixed method."""
    root, chosen = recordings(cfg, values["datasets"], "generalisation")
    every = fixed_methods()
    wanted = plain(cfg.algorithms)
    algorithms = every if wanted == "all" else [a for a in every if a in list(wanted)]
    if wanted != "all" and len(algorithms) != len(list(wanted)):
        bad = [a for a in list(wanted) if a not in every]
        raise UsageError(f"algorithms {', '.join(map(str, bad))} cannot be fixed entrants of "
                         f"sweep=generalisation; expected 'all' or a list from: "
                         f"{', '.join(every)}")
    return GeneralisationStudy(root, chosen, tuple(values["protocols"]), tuple(algorithms),
                               bool(values["peers"]), values["bootstrap"],
                               check_options(cfg, every), common["seed"],
                               common["call_timeout_s"], common["plugins"],
                               str(cfg.sweep.name))


def finish(study: GeneralisationStudy, out_dir: Path, common: dict) -> None:
    study.summarize(out_dir)


def figures(name: str, out_dir: Path) -> list[Path]:
    from magbench.figures.generalisation import generalisation_figure
    from magbench.figures.style import save_figure

    if not (out_dir / "generalisation_cases.csv").exists():
        return []
    import pandas as pd

    cases = pd.read_csv(out_dir / "generalisation_cases.csv")
    return [save_figure(generalisation_figure(cases), out_dir / "generalisation.png")]


def section(out_dir: Path) -> None:
    from magbench.report.generalisation import generalisation_section

    write_text_atomic(generalisation_section(out_dir.parent, out_dir.name) + "\n",
                      out_dir / "generalisation.md")


def report(results_dir: Path) -> str:
    from magbench.report.generalisation import generalisation_section

    return generalisation_section(results_dir)


KIND = register_kind(Kind(
    name="generalisation",
    what="fit on part of each real recording, score on the rest: calibrate vs fixed fits",
    keys=(
        Key("datasets", "all", "'all' or a list of recording folder names",
            lambda v, what: plain(v)),
        Key("protocols", list(PROTOCOLS), "which parts are fitted and scored: "
            + ", ".join(PROTOCOLS), one_or_more_of(PROTOCOLS)),
        Key("peers", True, "also score navlib's and magcal's fits when installed (the peers "
            "extra)", check_flag),
        Key("bootstrap", field_default(GeneralisationStudy, "bootstrap"), "block-bootstrap "
            "refits of the interval check (halves of recordings of two minutes or more; 0: no "
            "check)", integer(0, 10_000)),
    ),
    build=build, finish=finish, figures=figures, section=section, report=report,
    needs_data=True))
