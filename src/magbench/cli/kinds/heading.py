"""The heading study (direction of the calibrated field against an optical reference): a kind."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from omegaconf import DictConfig

from magbench.cli.config import (
    Key,
    UsageError,
    check_flag,
    check_options,
    check_trials,
    field_default,
    integer,
    nominal_point,
    number,
    plain,
    selected_algorithms,
)
from magbench.cli.kinds import Kind, register_kind
from magbench.core.files import write_text_atomic
from magbench.pipeline.fitting import PREPROCESSING
from magbench.sources.recordings import ATTITUDE_COLUMNS, GYRO_COLUMNS
from magbench.sources.semisynthetic import DISTORTIONS
from magbench.studies.heading import PARTS, PREPARED_CACHE, HeadingStudy


def _with_attitude(root: Path, names: list[str]) -> list[str]:
    """The recordings whose ``data.csv`` has gyro and attitude columns."""
    keep = []
    for name in names:
        header = set(pd.read_csv(root / name / "data.csv", nrows=0).columns)
        if set(GYRO_COLUMNS) | set(ATTITUDE_COLUMNS) <= header:
            keep.append(name)
    return keep


def _datasets(cfg: DictConfig, chosen: object) -> tuple[str, list[str]]:
    """The data folder and the recordings of the semi-synthetic and as-given parts."""
    from magbench.sources.recordings import data_dir, list_recordings

    try:
        root = data_dir(cfg.get("data_dir"))
    except ValueError as exc:
        raise UsageError(f"{exc} (or run the simulation alone: sweep.parts=[mc])") from None
    usable = _with_attitude(root, list_recordings(root))
    names = usable if chosen == "all" else [chosen] if isinstance(chosen, str) else list(chosen)
    bad = [d for d in names if d not in usable]
    if bad or not names:
        raise UsageError(f"recording(s) {', '.join(map(str, bad)) or '(none)'} in {root} have "
                         f"no gyro and attitude columns (gx..gz, qw..qz) or do not exist; "
                         f"expected 'all' or a list from: {', '.join(usable) or '(none)'}")
    return str(root), names


def build(cfg: DictConfig, common: dict, values: dict) -> HeadingStudy:
    """The heading study: simulation, semi-synthetic and as-given parts."""
    parts = values["parts"]
    root, datasets = (None, [])
    if set(parts) & {"semi", "given"}:
        root, datasets = _datasets(cfg, values["datasets"])
    algorithms = selected_algorithms(cfg, include_gyro=True, include_accel=True)
    nominal = nominal_point(cfg, 4)
    settings = {k: values[k] for k in ("distortions", "draws", "max_samples", "mount_deg",
                                       "preprocess", "tolerance", "rate_hz", "duration_s",
                                       "rate_rms", "gyro_noise", "accel_noise",
                                       "gyro_bias_max", "mount_max_deg", "lag_max_s",
                                       "correct_lag")}
    return HeadingStudy(
        algorithms=algorithms, parts=tuple(parts),
        trials=check_trials(cfg, "sweep heading") if "mc" in parts else 0, root=root,
        datasets=tuple(datasets), options=check_options(cfg, algorithms),
        seed=common["seed"], sigma=nominal.sigma, point=nominal,
        call_timeout_s=common["call_timeout_s"], plugins=common["plugins"],
        name=str(cfg.sweep.name), **settings,
        cache=str(Path(common["results_dir"]) / str(cfg.sweep.name) / PREPARED_CACHE)
        if root is not None else None)


def finish(study: HeadingStudy, out_dir: Path, common: dict) -> None:
    study.summarize(out_dir)


def figures(name: str, out_dir: Path) -> list[Path]:
    from magbench.figures.heading import write_heading_figures

    if not (out_dir / "correlation.csv").exists():
        return []
    return write_heading_figures(out_dir)


def section(out_dir: Path) -> None:
    from magbench.report.heading import heading_report_section

    write_text_atomic(heading_report_section(out_dir.parent), out_dir / "section.md")


def report(results_dir: Path) -> str:
    from magbench.report.heading import heading_report_section

    if not (Path(results_dir) / "heading" / "summary.csv").exists():
        return ""
    return heading_report_section(results_dir)


def _subset(allowed: tuple[str, ...]):
    def check(value: object, what: str) -> list[str]:
        value = plain(value)
        value = [value] if isinstance(value, str) else list(value or [])
        bad = [v for v in value if v not in allowed]
        if bad or not value:
            raise UsageError(f"{what} must be a non-empty list from {', '.join(allowed)}, "
                             f"got {value}")
        return list(dict.fromkeys(value))
    return check


def _one_of(allowed: tuple[str, ...]):
    def check(value: object, what: str) -> str:
        if value not in allowed:
            raise UsageError(f"{what} must be one of {', '.join(allowed)}, got {value!r}")
        return str(value)
    return check


def _d(name: str) -> object:
    return field_default(HeadingStudy, name)


def _angle(top: float):
    return number(lambda a: 0 <= a <= top, f"in [0, {top:g}] degrees")


KIND = register_kind(Kind(
    name="heading", what="heading error of every method against an optical reference "
    "(simulated, semi-synthetic and as-given recordings; data_dir)", keys=(
        Key("parts", list(PARTS), "mc (simulation), semi (recordings + known distortion), "
            "given (recordings as given)", _subset(PARTS)),
        Key("datasets", "all", "'all' (every recording with gyro and attitude columns) or a "
            "list of recording folder names", lambda v, what: plain(v)),
        Key("distortions", list(DISTORTIONS), "semi: eq80 (eq. 68 at the nominal point) and "
            "magnet (plus an attached magnet)", _subset(DISTORTIONS)),
        Key("draws", _d("draws"), "semi: distortions drawn per recording and kind",
            integer(1, 10_000)),
        Key("max_samples", _d("max_samples"), "fits see every ceil(n/max_samples)-th row",
            integer(16, 10_000_000)),
        Key("mount_deg", _d("mount_deg"), "semi: mounting rotation (deg, random axis)",
            _angle(180)),
        Key("preprocess", _d("preprocess"), "what each method sees (as sweep=real)",
            _one_of(PREPROCESSING)),
        Key("tolerance", _d("tolerance"), "clean rows: world field within this share of "
            "its strength of the median", number(lambda x: 0 < x <= 10, "in (0, 10]")),
        Key("rate_hz", _d("rate_hz"), "mc: sample rate (Hz)",
            number(lambda r: 0 < r <= 10_000, "in (0, 10000] Hz")),
        Key("duration_s", _d("duration_s"), "mc: manoeuvre length (s)",
            number(lambda d: 0 < d <= 3600, "in (0, 3600] s")),
        Key("rate_rms", _d("rate_rms"), "mc: RMS turn rate per axis (rad/s)",
            number(lambda r: 0 < r <= 50, "in (0, 50] rad/s")),
        Key("gyro_noise", _d("gyro_noise"), "mc: gyro noise std (rad/s)",
            number(lambda x: 0 <= x <= 10, "in [0, 10] rad/s")),
        Key("accel_noise", _d("accel_noise"), "mc: accelerometer noise std (m/s^2)",
            number(lambda x: 0 <= x <= 100, "in [0, 100] m/s^2")),
        Key("gyro_bias_max", _d("gyro_bias_max"), "mc: gyro bias uniform in +-this (rad/s)",
            number(lambda b: 0 <= b <= 10, "in [0, 10] rad/s")),
        Key("mount_max_deg", _d("mount_max_deg"), "mc: mounting rotation uniform in [0, "
            "this] degrees", _angle(180)),
        Key("lag_max_s", _d("lag_max_s"), "mc: magnetometer lag uniform in [0, this] s",
            number(lambda x: 0 <= x <= 1, "in [0, 1] s")),
        Key("correct_lag", _d("correct_lag"), "measure the magnetometer lag and remove it "
            "before fitting and scoring", check_flag),
    ),
    build=build, finish=finish, figures=figures, section=section, report=report,
    needs_data=True))
