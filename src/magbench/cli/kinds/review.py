"""The review's sweeps (baseline, gamma, beta, K, sigma, coverage, option sweeps): a kind."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from omegaconf import DictConfig

from magbench.cli.config import (
    Key,
    UsageError,
    check_number,
    check_options,
    check_trials,
    nominal_point,
    plain,
    point_checks,
    selected_algorithms,
)
from magbench.cli.kinds import Kind, register_kind
from magbench.methods.registry import get_method


def build(cfg: DictConfig, common: dict, values: dict):
    """The review sweep: ``trials`` datasets at each point (one varied parameter, explicit
    points, or one method option varied on the same datasets)."""
    from magbench.studies.review import POINT_COLUMNS, ReviewStudy, point_with

    algorithms = selected_algorithms(cfg)
    min_k = max(get_method(a).min_samples for a in algorithms)
    base = nominal_point(cfg, min_k)
    sweep = cfg.sweep
    vary = sweep.get("vary")
    varied = list(plain(sweep.get("values")) or [])
    if vary and not varied:
        raise UsageError(f"sweep {sweep.name!r} varies {vary} but lists no values")
    axis = None
    if isinstance(vary, str) and vary.startswith("options."):
        axis = _option_axis(vary, varied, algorithms)
        vary = None
    if vary is not None and vary not in POINT_COLUMNS:
        raise UsageError(f"sweep.vary must be one of {', '.join(POINT_COLUMNS)}, "
                         f"options.<method>.<option> or null, got {vary!r}")
    changes = [{vary: v} for v in varied] if vary else [dict(c) for c in values["points"]]
    checks = point_checks(min_k)
    for change in changes:
        for key, v in change.items():
            if key not in checks:
                raise UsageError(f"sweep point sets {key!r}; a point has "
                                 f"{', '.join(POINT_COLUMNS)}")
            check_number(v, f"sweep value {key}", *checks[key])
    return ReviewStudy(str(sweep.name), [point_with(base, c) for c in changes],
                       check_trials(cfg, f"sweep {sweep.name}"), common["seed"], algorithms,
                       check_options(cfg, algorithms), common["delta"],
                       common["call_timeout_s"], common["plugins"], axis)


def _option_axis(vary: str, values: list, algorithms: list[str]):
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


def finish(study, out_dir: Path, common: dict) -> None:
    """The timing pass for tau (after the trials, workers gone), summary.csv, the tables and
    efficiency.csv (bound / MSE with its interval per point and method)."""
    from magbench.report.build import write_sweep_tables
    from magbench.studies.review import SELECTION_RECORD, write_efficiency
    from magbench.studies.timing import timing_is_current, write_timing

    if not timing_is_current(study, out_dir) and not _extend_timing(study, out_dir, common):
        write_timing(study, out_dir, progress=common["progress"])
    summary = study.summarize(out_dir)
    write_sweep_tables(study.name, summary, out_dir, delta=study.delta)
    if study.axis is not None or not _extend_efficiency(study, out_dir):
        write_efficiency(out_dir, study.name, [] if study.axis is None else [study.axis.column])
    record = {"fingerprint": study.fingerprint()}
    if study.has_selection():
        record[SELECTION_RECORD] = study.selection_record(out_dir)
    _write_json(out_dir / EFFICIENCY_RECORD, record)


#: Beside efficiency.csv: the fingerprint of the run it was computed from.
EFFICIENCY_RECORD = "efficiency.json"


def _write_json(path: Path, data: dict) -> None:
    import json

    from magbench.core.files import write_text_atomic

    write_text_atomic(json.dumps(data), path)


def _extend_efficiency(study, out_dir: Path) -> bool:
    """After a run that reused some methods' rows, keep their rows of efficiency.csv (each
    group's bootstrap has its own stream: a method's interval depends on its rows alone) if
    that file was computed from the run they came from (``efficiency.json``), and compute
    the others'; False (nothing written) otherwise. The table is the one a whole computation
    writes: groups in the order of the trials, point by point, methods in order."""
    import json

    from magbench.core.files import read_csv_columns, write_csv_atomic
    from magbench.studies.review import POINT_COLUMNS, efficiency_intervals

    try:
        record = json.loads((out_dir / "run.json").read_text())
        made_from = json.loads((out_dir / EFFICIENCY_RECORD).read_text())["fingerprint"]
        old = pd.read_csv(out_dir / "efficiency.csv")
    except (OSError, ValueError, KeyError, TypeError):
        return False
    reused, source = record.get("methods_reused") or [], record.get("reused_from")
    if not reused or not source or made_from != source:
        return False
    by = [*POINT_COLUMNS, "algorithm"]
    trials = read_csv_columns(out_dir / "trials.csv", [*by, "meaningful", "crb", "sq_err"])
    fresh = efficiency_intervals(trials[~trials["algorithm"].isin(reused)], by, study.name)
    kept = old[old["algorithm"].isin(reused)]
    rows = {name: [r for _, r in frame[frame["algorithm"] == name].iterrows()]
            for frame, names in ((kept, reused), (fresh, fresh["algorithm"].unique()))
            for name in names}
    sizes = trials.groupby(by, sort=False, dropna=False).size()   # in efficiency's order
    order = [key[-1] for key in sizes.index]
    counts = {name: order.count(name) for name in set(order)}
    if any(len(rows.get(name, [])) != n for name, n in counts.items()):
        return False
    taken = {name: iter(rows[name]) for name in counts}
    table = pd.DataFrame([next(taken[name]) for name in order], columns=old.columns)
    if not (table["n"].to_numpy() == sizes.to_numpy()).all():   # a file of other rows
        return False
    write_csv_atomic(table.astype(old.dtypes.to_dict()), out_dir / "efficiency.csv")
    return True


def _extend_timing(study, out_dir: Path, common: dict) -> bool:
    """After a run that reused some methods' rows (``run.json``'s ``methods_reused``), keep
    their cells of the timing pass of the run they came from and time only the methods it
    computed; False (nothing written) when there is no such pass to extend."""
    import json
    import sys
    import time

    from magbench.core.files import write_csv_atomic
    from magbench.studies.review import POINT_COLUMNS
    from magbench.studies.timing import TIMING_FILE, read_timing, time_methods

    try:
        record = json.loads((out_dir / "run.json").read_text())
    except (OSError, ValueError):
        return False
    reused, source = record.get("methods_reused") or [], record.get("reused_from")
    old = read_timing(out_dir)
    if not reused or not source or old is None or "fingerprint" not in old:
        return False
    if set(old["fingerprint"].astype(str)) != {source}:
        return False
    kept = old[old["algorithm"].isin(reused)]
    if len(kept) != len(reused) * len(study.points):
        return False
    start = time.perf_counter()
    computed = [m for m in study.algorithms if m not in reused]
    new = (time_methods(study.points, study.seed, computed, study.options,
                        call_timeout_s=study.call_timeout_s) if computed else kept.iloc[:0])
    frame = pd.concat([kept, new], ignore_index=True)
    # The cells in the order a whole pass writes them: point by point, methods in order.
    point = {tuple(getattr(p, c) for c in POINT_COLUMNS): i for i, p in enumerate(study.points)}
    order = {m: i for i, m in enumerate(study.algorithms)}
    frame["_cell"] = [(point.get(tuple(v[:-1]), 0), order[v[-1]]) for v in
                      frame[[*POINT_COLUMNS, "algorithm"]].itertuples(index=False)]
    frame = frame.sort_values("_cell", kind="stable").drop(columns="_cell")
    frame["fingerprint"] = study.fingerprint()
    write_csv_atomic(frame, out_dir / TIMING_FILE)
    if common["progress"]:
        print(f"{study.name}: timing pass of {', '.join(computed) or 'no method'} (the others' "
              f"kept), {time.perf_counter() - start:.1f} s", file=sys.stderr)
    return True


def figures(name: str, out_dir: Path) -> list[Path]:
    """The sweep's figure: Figures 2-5, the coverage figure, or a method-option figure."""
    from magbench.figures.options import option_column, write_option_figure
    from magbench.figures.sweeps import FIGURES, write_figure
    from magbench.studies.review import with_coverage_column
    from magbench.studies.timing import read_timing

    if not (out_dir / "summary.csv").exists():
        return []
    summary = pd.read_csv(out_dir / "summary.csv")
    if option_column(summary):
        return [write_option_figure(summary, out_dir, name)]
    if name not in FIGURES:
        return []
    timing = read_timing(out_dir)
    if FIGURES[name].x == "coverage":
        summary = with_coverage_column(summary)
        timing = None if timing is None else with_coverage_column(timing)
    return list(write_figure(summary, name, out_dir, timing))[:1]


def report(results_dir: Path) -> str:
    """The method variants beside the methods they vary (the baseline's rows)."""
    from magbench.report.variants import variants_report_section

    return variants_report_section(results_dir)


KIND = register_kind(Kind(
    name="review", what="the review's synthetic sweeps (eq. 80): one parameter varied, explicit "
    "points, or a method option", keys=(
        Key("points", [{}], "explicit points as changes to the nominal point, e.g. "
            "[{cap_deg: 90}, {band_deg: 10}] (used when vary is null)", plain),),
    build=build, finish=finish, figures=figures, report=report, timed=True))
