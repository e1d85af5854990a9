"""Wu and Shi's own simulation study (their section IV): a kind."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from magbench.cli.config import (
    Key,
    UsageError,
    check_integer,
    check_options,
    check_trials,
    field_default,
    integer,
    is_list_of,
    number,
    plain,
    selected_algorithms,
)
from magbench.cli.kinds import Kind, register_kind
from magbench.core.files import write_csv_atomic, write_text_atomic
from magbench.methods.registry import get_method
from magbench.studies.wushi import ML, NM, WuShiStudy

#: The largest sample size a run or a timing point may ask for (memory: K x 3 x a few copies).
MAX_N = 1_000_000


def build(cfg: DictConfig, common: dict, values: dict) -> WuShiStudy:
    """Wu and Shi's simulation study: ``trials`` Monte Carlo runs of their section IV."""
    algorithms = selected_algorithms(cfg)
    names = [*dict.fromkeys([ML, NM, *algorithms])]
    min_n = max(get_method(m).min_samples for m in names)
    check_integer(values["N"], "sweep.N", min_n, MAX_N)
    for i, n in enumerate(values["time_N"]):
        check_integer(n, f"sweep.time_N[{i}]", min_n, MAX_N)
    return WuShiStudy(
        runs=check_trials(cfg, "sweep wushi"), N=values["N"], sigma=values["sigma"],
        seed=common["seed"], algorithms=tuple(algorithms),
        alphas_pct=tuple(values["alphas_pct"]), thresholds=values["thresholds"],
        time_N=tuple(values["time_N"]), time_repeats=values["time_repeats"],
        time_calls=values["time_calls"], max_iter=values["max_iter"],
        converge_within=values["converge_within"], control_runs=values["control_runs"],
        claimed_ratio=values["claimed_ratio"], options=check_options(cfg, names),
        call_timeout_s=common["call_timeout_s"], plugins=common["plugins"],
        name=str(cfg.sweep.name))


def finish(study: WuShiStudy, out_dir: Path, common: dict) -> None:
    from magbench.studies import wushi

    wushi.finish(study, out_dir)


def figures(name: str, out_dir: Path) -> list[Path]:
    from magbench.figures.wushi import write_wushi_figures

    return write_wushi_figures(out_dir) if (out_dir / "fig5_time.csv").exists() else []


def section(out_dir: Path) -> None:
    """The claims table and the study's Markdown beside its files."""
    from magbench.report.wushi import evaluate_claims, wushi_report_section
    from magbench.studies.wushi import read_settings

    settings = read_settings(out_dir)
    claims = evaluate_claims(out_dir.parent, int(float(settings["converge_within"])),
                             float(settings["claimed_ratio"]))
    write_csv_atomic(claims, out_dir / "claims.csv")
    write_text_atomic(wushi_report_section(out_dir.parent, link_prefix=""), out_dir / "wushi.md")


def report(results_dir: Path) -> str:
    from magbench.report.wushi import wushi_report_section

    return wushi_report_section(results_dir)


def _thresholds(value: object, what: str) -> dict:
    value = plain(value)
    if not isinstance(value, dict) or set(value) != {"ML", "NM"}:
        raise UsageError(f"{what} must have keys ML and NM, got {value!r}")
    return {k: number(lambda x: x > 0, "> 0")(v, f"{what}.{k}") for k, v in value.items()}


def _default(name: str) -> object:
    value = field_default(WuShiStudy, name)
    return list(value) if isinstance(value, tuple) else value


def _positive(high: int) -> object:
    return integer(1, high)


KIND = register_kind(Kind(
    name="wushi", what="Wu and Shi's simulation study (Table I, Figures 3, 5, 6)", keys=(
        Key("N", _default("N"), "samples per run", integer(1, MAX_N)),
        Key("sigma", _default("sigma"), "noise std (gauss)",
            number(lambda x: 0 <= x <= 1e3, "in [0, 1000]")),
        Key("alphas_pct", _default("alphas_pct"), "Fig. 6 initial-estimate perturbations (%)",
            is_list_of(number(lambda x: 0 <= x <= 1e3, "in [0, 1000] %"))),
        Key("thresholds", _default("thresholds"), "Fig. 6 divergence: final objective (4) / "
            "(11) above", _thresholds),
        Key("max_iter", _default("max_iter"), "Gauss-Newton iteration cap of ML and NM",
            _positive(100_000)),
        Key("converge_within", _default("converge_within"), "Fig. 3 claim: iterations to "
            "convergence", _positive(100_000)),
        Key("time_N", _default("time_N"), "Fig. 5 sample sizes", is_list_of(integer(1, MAX_N))),
        Key("time_repeats", _default("time_repeats"), "data sets per N (median plotted)",
            _positive(1000)),
        Key("time_calls", _default("time_calls"), "calls per data set (the fastest counts)",
            _positive(1000)),
        Key("claimed_ratio", _default("claimed_ratio"), "Fig. 5 claim: ML / NM time at "
            "N = 1000", number(lambda x: x > 0, "> 0")),
        Key("control_runs", _default("control_runs"), "first runs also calibrated with the "
            "true offset removed", integer(0, 1_000_000)),
    ),
    build=build, finish=finish, figures=figures, section=section, report=report))
