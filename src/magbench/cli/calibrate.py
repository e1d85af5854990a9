"""``python -m magbench calibrate file=PATH [method=NAME] [columns=[mx,my,mz]] [out=DIR]``.

Calibrates a user's own recording: the adapter between the command line and the pipeline of
:mod:`magbench.pipeline` (read -> screen -> fit -> choose -> gate -> export -> picture; its
notes name the module of each step). This module checks the keys, reads the file, runs
:func:`magbench.pipeline.decision.decide` (thinning by direction and the outlier screen,
coverage and the models it allows, every candidate fitted on all samples and on interleaved
time-block folds, the choice that holds out of sample, trimming around the chosen fit, refusal
of collapsed fits, verdict, intervals and the PASS / WARN / FAIL gate), has the export and
picture steps write, prints the answer first (status, held-out error, method, folder), then
the reasons and the details, and sets the exit status. FAIL exits 3 and writes
``calibration.json`` with the reasons, the ranking and the picture, no correction
(thresholds: the ``gate.*`` keys, :func:`check_gate`; a field strength the Earth does not give
in the declared unit, :func:`magbench.core.units.unit_check`). Every file goes to a staging
folder put in place as ``out`` in one step, under a lock (:mod:`magbench.cli.outfolder`).
The candidates are the registered methods except the review's printed variants (family
``variant``: benchmark-only, wrong as printed) and, without gyro data, the gyro-aided ones.
By default (``candidates=auto``) they are fitted in two rounds: the closed forms and Wu-Shi NM
first, the iterative rest only when they could change the choice (the rule is in
:mod:`magbench.pipeline.rounds`); ``candidates=all`` fits every one in one round,
``candidates=[a,b]`` only those, and ``method=NAME`` runs any one.

The chosen (or the named) calibration is written in the safe gauge of
:mod:`magbench.core.gauge`: the correction a firmware applies is ``m = A (y - b)`` with
``A = (T T^T)^(-1/2)`` symmetric positive definite and ``b = h``, in the recording's units
(never a mirror image; the rotation removed from the method's own ``T^-1`` is reported), or,
when the inertial columns fix the rotation, heading-true ``A = R S``
(:mod:`magbench.cli.direction`; the firmware files then say what part of R they leave out).
Beside ``calibration.json`` (:mod:`magbench.pipeline.export`) go ``calibration.h``,
the firmware files that accept the values (:mod:`magbench.core.exports`), ``ranking.csv``,
``manifest.json`` and ``calibration.png`` (:mod:`magbench.pipeline.picture`). The default
folder is ``<name>-calibration`` with ``name`` the file's stem, or its folder's name for a
file called ``data.csv``.
The preprocessing is ``centre`` (remove the sphere-fit centre and radius first), which the
real-data sweep found necessary for MAG.I.C.AL and Dorveaux when the offset exceeds the field
radius; ``preprocess=scale`` selects the review's.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from magbench.cli.config import (
    UsageError,
    check_columns,
    check_common,
    check_compensate,
    check_field_strength,
    check_instance,
    check_integer,
    check_number,
    check_options,
    check_site,
    check_units,
    did_you_mean,
    overwrite_wanted,
    picture_wanted,
)
from magbench.cli.direction import direction_lines, mark_vetoes
from magbench.cli.outfolder import Staging, hold
from magbench.cli.picture import PictureWorker, draw_picture
from magbench.core.files import write_records_csv, write_text_atomic
from magbench.core.model import Calibration
from magbench.core.units import Units
from magbench.core.verdict import Gate
from magbench.methods.registry import methods
from magbench.pipeline.auto import candidate_rounds
from magbench.pipeline.bootstrap import bootstrap_check
from magbench.pipeline.decision import decide
from magbench.pipeline.export import (
    add_mounting,
    add_time_varying,
    calibration_json,
    held_out_rms_pct,
    instance_keys,
    write_exports,
)
from magbench.pipeline.fitting import DEFAULT_MAX_SAMPLES, PREPROCESSING, applicability
from magbench.pipeline.holdout import estimate
from magbench.pipeline.picture import picture_job
from magbench.pipeline.reading import MIN_COVERAGE, read_recording, recording_units
from magbench.pipeline.result import CalibrationResult
from magbench.sources.recordings import Recording

__all__ = ["MIN_COVERAGE", "answer_line", "check_gate", "default_out", "detail_lines",
           "run_calibrate"]


def _candidates(cfg: DictConfig, rec_has_gyro: bool) -> tuple[list[str], list[str]]:
    """The first and second round of candidates (``second_round`` of
    :func:`~magbench.pipeline.calibration.calibrate_recording`) from ``method`` and
    ``candidates`` (:func:`magbench.pipeline.auto.candidate_rounds`, as the Python API)."""
    name = cfg.get("method")
    if name is not None:
        return [str(name)], []
    chosen = cfg.get("candidates", "auto")
    return candidate_rounds(rec_has_gyro, chosen if chosen in ("auto", "all") else
                            [str(c) for c in chosen])


def _check_candidates(cfg: DictConfig) -> None:
    """``candidates``: auto, all or a list of registered methods (exit 2 otherwise)."""
    value = cfg.get("candidates", "auto")
    if value in ("auto", "all"):
        return
    names = list(OmegaConf.to_container(value)) if OmegaConf.is_list(value) else None
    if not names or not all(isinstance(n, str) for n in names):
        raise UsageError(f"candidates must be auto, all or a list of method names, e.g. "
                         f"candidates=[fang,magical], got {value!r}")
    unknown = [n for n in names if n not in methods()]
    if unknown:
        raise UsageError(f"candidates: unknown method(s) {', '.join(unknown)}; expected names "
                         f"from: {', '.join(methods())}")
    if cfg.get("method") is not None:
        raise UsageError("give either method=NAME (one method) or candidates=[...], not both")


def default_out(path: Path) -> Path:
    """``<stem>-calibration``, or ``<folder>-calibration`` for a file called ``data.csv``
    (every recording of the real-data layout has that name)."""
    stem = path.resolve().parent.name if path.name.lower() == "data.csv" else path.stem
    return Path(f"{stem or 'recording'}-calibration")


def answer_line(payload: dict, out: Path) -> str:
    """The first line of the output: the status, the error, the method and where it went."""
    v = payload["verdict"]
    where = "" if v["held_out"] else ", in sample"
    target = f"-> {out}/" if payload["status"] != "FAIL" else f"(nothing to flash; {out}/" \
        "calibration.json says why)"
    measured = v.get("heading_measured_deg")
    heading = (f"heading {measured:.1f} deg RMS (held out, against the attitude)"
               if measured is not None else f"heading ~{v['heading_error_deg']['p95']:.1f} deg")
    return (f"{payload['status']:<4}  field error {v['field_error_pct']['p95']:.1f} % "
            f"(p95{where}), {heading}, {payload['method']} ({payload['model']} model) "
            f"{target}")


def _interval_lines(payload: dict) -> list[str]:
    """b and A with the wider of the model-based and the block-bootstrap half-widths."""
    iv, bs = payload["intervals"], payload["bootstrap"]
    if not iv:
        return []
    h, A = np.array(iv["h"]), np.array(iv["A"])
    hh, Ah = np.array(iv["h_half_width"]), np.array(iv["A_half_width"])
    src_h = src_A = "model-based"
    if bs:
        hh, Ah = np.array(bs["wider_h"]), np.array(bs["wider_A"])
        src_h, src_A = bs["source_h"], bs["source_A"]
    lines = ["b = " + ", ".join(f"{x:.4g} +- {e:.2g}" for x, e in zip(h, hh, strict=True))
             + f" (95 %, {src_h})"]
    if iv["model"] == "bias":
        lines.append(f"A = {A[0, 0]:.4g} I, fixed (offset-only model: A is not estimated)")
    elif iv["model"] == "sphere":
        lines.append(f"A = s I, s = {A[0, 0]:.4g} +- {Ah[0, 0]:.2g} (95 %, {src_A})")
    else:
        lines.append("A diagonal " + ", ".join(f"{A[i, i]:.4g} +- {Ah[i, i]:.2g}"
                                               for i in range(3))
                     + f", off-diagonal +- {max(Ah[0, 1], Ah[0, 2], Ah[1, 2]):.2g} at most "
                     f"(95 %, {src_A})")
    if bs:
        lines.append(f"intervals: wider of model-based and block bootstrap ({bs['replicates']} "
                     f"refits, blocks of {bs['block']} samples, residual correlation "
                     f"{bs['correlation_samples']:.1f} samples)"
                     + ("; b at least as wide as the two halves' offsets are apart"
                        if "halves_apart_h" in bs else ""))
    return lines


def detail_lines(result: CalibrationResult, payload: dict, n_file: int) -> list[str]:
    """The lines after the answer: samples, coverage, choice, table, intervals, gauge."""
    cover = result.coverage
    used = f"fitted {result.work.K}" + (f" (1 in {result.stride})" if result.stride > 1 else "")
    g = payload["removed"]
    lines = [
        f"samples: {n_file} in the file; {result.thinned} thinned by direction (still or slow "
        f"stretches), {result.outliers} outliers set aside; {used}",
        f"coverage: {cover['coverage']:.2f} of the sphere, largest gap "
        f"{cover['largest_gap_deg']:.0f} deg, {result.directions} distinct directions",
        f"choice: {result.how}",
        _table(result.ranked),
    ]
    if result.second_round:
        lines.append(f"second round fitted: {result.second_round}")
    elif result.not_fitted:
        names = result.not_fitted
        shown = ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "")
        lines.append(f"not fitted: {shown} (candidates=all fits every method)")
    lines += _interval_lines(payload)
    gauge = ("then turned to the IMU's axes: A = R S, heading-true" if payload.get("direction")
             else "A symmetric positive definite")
    lines.append(f"field strength {_field_text(payload)}; a "
                 f"{g['rotation_deg']:.1f} deg rotation"
                 f"{' and a mirror image' if g['mirrored'] else ''} removed ({gauge})")
    return lines


def _field_text(payload: dict) -> str:
    """The field strength in the recording's unit, and against the expected one if given."""
    units = Units.from_dict(payload.get("unit"))
    text = units.show(payload["field_strength"])
    expected = payload.get("field_strength_expected")
    if expected:
        change = 100 * (payload["field_strength"] / expected - 1)
        text += f" (expected {units.show(expected)}: {change:+.1f} %)"
    return text


def _fmt(x: float, width: int = 11, spec: str = ".3g") -> str:
    return f"{x:{width}{spec}}" if np.isfinite(x) else f"{'-':>{width}}"


def _table(ranked: list[dict]) -> str:
    lines = [f"{'rank':>4}  {'method':<12}{'model':<9}{'J_r in':>9}{'J_r out':>9}"
             f"{'worst':>9}{'p95 %':>7}  note"]
    for r in ranked:
        rank = "-" if r["rank"] is None else str(r["rank"])
        note = ("tie; " if r["tie"] else "") + (r["note"] or "")
        lines.append(f"{rank:>4}  {r['algorithm']:<12}{r['model']:<9}"
                     f"{_fmt(r['J_r_in'], 9, '.2e')}{_fmt(r['J_r_out'], 9, '.2e')}"
                     f"{_fmt(r['J_r_worst'], 9, '.2e')}{_fmt(r['p95_out_pct'], 7, '.2f')}  "
                     f"{note.rstrip('; ')}")
    return "\n".join(lines)


def check_gate(cfg: DictConfig) -> Gate:
    """The ``gate.*`` keys of calibrate: numbers, each WARN threshold on the safe side of its
    FAIL threshold (exit 2 otherwise)."""
    given = cfg.get("gate") or {}
    values = {}
    for key, default in Gate().__dict__.items():
        value = given.get(key, default)
        if isinstance(default, int):
            values[key] = check_integer(value, f"gate.{key}", 0)
        else:
            values[key] = check_number(value, f"gate.{key}", lambda x: x >= 0, ">= 0")
    gate = Gate(**values)
    for low, high in (("warn_error_pct", "fail_error_pct"), ("warn_gap_deg", "fail_gap_deg"),
                      ("fail_directions", "warn_directions"),
                      ("warn_field_pct", "fail_field_pct"),
                      ("warn_heading_deg", "fail_heading_deg")):
        if getattr(gate, low) > getattr(gate, high):
            raise UsageError(f"gate.{low} must not exceed gate.{high}, got "
                             f"{getattr(gate, low)} > {getattr(gate, high)}")
    unknown = sorted(set(given) - set(Gate().__dict__))
    if unknown:
        raise UsageError(f"unknown gate key(s) {', '.join(unknown)}; expected: "
                         f"{', '.join(Gate().__dict__)}")
    return gate


def run_calibrate(cfg: DictConfig, picture: PictureWorker | None = None) -> int:
    """The ``calibrate`` command; a bad file or value raises :class:`UsageError`.

    Returns 0 for PASS and WARN, 3 for FAIL (``calibration.json`` with the reasons, the
    ranking and the picture; no correction, no firmware file). ``picture``: a started
    :class:`~magbench.cli.picture.PictureWorker` draws ``calibration.png`` in parallel
    (:func:`magbench.cli.main.main` starts one); without it the picture is drawn here. The file
    is the same either way. Every file goes to a staging folder put in place as ``out`` at the
    end, under a lock taken before the overwrite check (:mod:`magbench.cli.outfolder`).
    """
    start = time.perf_counter()
    run = _settings(cfg)
    with hold(run.out, run.overwrite) as staging:
        code = _calibrate_into(cfg, run, staging, picture, start)
        staging.commit()
    return code


def _calibrate_into(cfg: DictConfig, run: _Run, staging: Staging,
                    picture: PictureWorker | None, start: float) -> int:
    """The work of :func:`run_calibrate`, writing into ``staging``; the exit status."""
    rec = _read(run)
    n_file = rec.K
    candidates, second = _candidates(cfg, rec.has_gyro)
    options = check_options(cfg, candidates + second)
    if run.name is not None:
        reason = applicability(run.name, rec)
        if reason:
            raise UsageError(reason.removeprefix("skipped: "))
    if _nothing_cached():
        print("magbench: compiling the fitting kernels on this first run (once; later runs "
              "reuse them)", file=sys.stderr, flush=True)
    decision = decide(rec, candidates, second_round=second, preprocess=run.preprocess,
                      options=options, seed=run.common["seed"],
                      call_timeout_s=run.common["call_timeout_s"], max_samples=run.max_samples,
                      gate=run.gate, expected_field=run.expected, compensate=run.compensate,
                      units=run.units, consume=True)
    rec, result, lag, offsets, veto = (decision.rec, decision.result, decision.lag_s,
                                       decision.offsets, decision.veto)
    mark_vetoes(result.ranked, veto)
    if result.chosen is None:
        _print_skipped(result.ranked)
        raise UsageError("no method produced a calibration that can be written ("
                         + ("no out-of-sample score: name one with method=NAME, or record "
                            "longer" if not run.name else "see the table")
                         + "); check that the sensor was turned through many orientations "
                         "in a steady field"
                         + ("; " + offsets.warning() if offsets is not None else ""))
    out, folder = run.out, staging.path
    units = decision.units
    payload = calibration_json(result, file=str(run.path), columns=list(rec.columns),
                               n_file=n_file, preprocess=run.preprocess, units=units.units,
                               expected_field=run.expected)
    if units.inferred:
        payload["unit"]["inferred"] = True
    payload |= instance_keys(rec)
    varying, corrected = add_time_varying(result, payload, run.compensate, options)
    first = [units.note] if units.note else []
    if payload["status"] == "FAIL":
        job = picture_job(result, payload, folder)
        write_records_csv(result.ranked, folder / "ranking.csv")
        write_text_atomic(json.dumps(payload, indent=2) + "\n", folder / "calibration.json")
        drawn = _draw(run, picture, job)
        _report(result, payload, out, n_file, ["calibration.json (the reasons; no correction)",
                                               "ranking.csv", *drawn], start,
                [line for line in (varying, _cure_line(payload)) if line], first)
        return 3
    mounting = add_mounting(result, payload, corrected)
    job = picture_job(result, payload, folder)
    sent = run.picture and picture is not None and picture.send(job)
    # After the picture is handed over, so that its drawing and the refits overlap.
    result.bootstrap = payload["bootstrap"] = bootstrap_check(
        result, run.n_boot, preprocess=run.preprocess, options=options,
        seed=run.common["seed"])
    cal, direction = direction_lines(result, Calibration(*estimate(result.chosen)), payload,
                                     veto, run.site, lag)
    write_text_atomic(json.dumps(payload, indent=2) + "\n", folder / "calibration.json")
    written, notes = write_exports(cal, payload, folder, result)
    offset_line = offsets.line() if offsets is not None else ""
    notes = [line for line in (offset_line, varying, mounting, *direction) if line] + notes
    write_records_csv(result.ranked, folder / "ranking.csv")
    drawn = _draw(run, picture if sent else None, job, sent=sent)
    _report(result, payload, out, n_file, ["calibration.json (m = A (y - b))", *written,
                                          "ranking.csv", *drawn], start, notes, first)
    return 0


def _draw(run: _Run, picture: PictureWorker | None, job: dict, *, sent: bool | None = None
          ) -> list[str]:
    """The picture, by the worker if it has (or takes) the job, else here; its name, or none
    when ``picture=false``."""
    if not run.picture:
        return []
    if sent is None:
        sent = picture is not None and picture.send(job)
    problem = picture.wait() if sent and picture is not None else ""
    if problem:
        print(f"magbench: note: {problem}; drawing the picture here", file=sys.stderr)
    if problem or not sent:
        draw_picture(job)
    return ["calibration.png"]


def _nothing_cached() -> bool:
    """Whether numba has cached none of the fitting kernels yet (beside their modules, or in
    ``NUMBA_CACHE_DIR``): the first run then spends a while compiling, said in one line."""
    import magbench.methods.algorithms as algorithms

    where = os.environ.get("NUMBA_CACHE_DIR")
    folder = Path(where) if where else Path(algorithms.__file__).parent / "__pycache__"
    return (folder.is_dir() and next(folder.rglob("*.nbi"), None) is None) or not folder.is_dir()


def _print_skipped(ranked: list[dict]) -> None:
    """Why no candidate was written: the table when some were ranked, else one line (a
    5-row file gives every method the same kind of reason)."""
    if any(r["rank"] is not None for r in ranked):
        print(_table(ranked))
        return
    notes = [str(r["note"] or "no out-of-sample score") for r in ranked]
    common = max(set(notes), key=notes.count)
    print(f"no candidate has an out-of-sample score ({len(ranked)} tried), e.g. "
          f"{ranked[notes.index(common)]['algorithm']}: {common.removeprefix('skipped: ')}")


@dataclass(frozen=True)
class _Run:
    """The checked keys of one ``calibrate`` command."""

    common: dict
    path: Path
    preprocess: str
    max_samples: int
    n_boot: int
    gate: object
    columns: list | None
    units: object
    expected: object
    instance: object
    compensate: object
    site: object
    out: Path
    name: str | None
    picture: bool
    overwrite: bool


def _settings(cfg: DictConfig) -> _Run:
    """Every key ``calibrate`` reads, checked before the file is read (so a misspelt option is
    named as such)."""
    common = check_common(cfg)
    if not cfg.get("file"):
        raise UsageError("calibrate needs file=PATH, a CSV of magnetometer samples (columns "
                         "mx,my,mz, or choose them with columns=[...])")
    path = Path(str(cfg.file))
    preprocess = str(cfg.get("preprocess", "centre"))
    if preprocess not in PREPROCESSING:
        raise UsageError(f"preprocess must be one of {', '.join(PREPROCESSING)}, got "
                         f"{preprocess!r}")
    units = recording_units(path, check_units(cfg))
    out = Path(str(cfg.out)) if cfg.get("out") else default_out(path)
    overwrite = overwrite_wanted(cfg)
    name = cfg.get("method")
    if name is not None and str(name) not in methods():
        guess = did_you_mean(str(name), methods())
        raise UsageError(f"unknown method {name!r}" + (f" (did you mean {guess}?)" if guess
                                                       else "")
                         + f"; expected one of: {', '.join(methods())}")
    _check_candidates(cfg)
    check_options(cfg, [str(name)] if name is not None else methods())
    return _Run(common, path, preprocess,
                check_integer(cfg.get("max_samples", DEFAULT_MAX_SAMPLES), "max_samples", 8),
                check_integer(cfg.get("bootstrap", 50), "bootstrap", 0, 10_000),
                check_gate(cfg), check_columns(cfg), units, check_field_strength(cfg, units),
                check_instance(cfg), check_compensate(cfg), check_site(cfg), out,
                None if name is None else str(name), picture_wanted(cfg), overwrite)


def _read(run: _Run) -> Recording:
    """The recording (:func:`magbench.pipeline.reading.read_recording`), its reader's warnings
    printed one line each; one line if unreadable."""
    try:
        return read_recording(run.path, run.columns, method=run.name, instance=run.instance,
                              compensate=run.compensate,
                              warn=lambda m: print(f"magbench: warning: {m}", file=sys.stderr))
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def _cure_line(payload: dict) -> str:
    """On a FAIL whose time-varying terms were kept: the held-out error with them, since a
    field that moves with the current (or temperature) is what failed, not the sensor."""
    tv = payload.get("time_varying") or {}
    if not tv.get("kept"):
        return ""
    rms = held_out_rms_pct(tv)
    return (f"the field moves with the {', '.join(tv['regressors'])}: with the terms the "
            f"held-out field magnitude error is {rms['time_varying']:.2f} % RMS against "
            f"{rms['static']:.2f} % static, but the verdict judges the static calibration; "
            "calibration.json holds the terms (time_varying), or record with the "
            f"{', '.join(tv['regressors'])} steady")


def _report(result: CalibrationResult, payload: dict, out: Path, n_file: int,
            written: list[str], start: float, notes: Sequence[str] = (),
            first: Sequence[str] = ()) -> None:
    """Print the answer first, then the reasons, ``first`` (the unit's line: it decides
    which firmware files exist), the details and what was written; the coverage advice and
    other warnings go to stderr."""
    lines = [answer_line(payload, out)]
    lines += [f"  {payload['status'].lower()}: {r}" for r in payload["fitness"]["reasons"]]
    lines += list(first)
    lines += detail_lines(result, payload, n_file)
    lines += list(notes)
    lines.append(f"wrote {out}/: {', '.join(written)} (in {time.perf_counter() - start:.2f} s)")
    print("\n".join(lines))
    for warning in payload["warnings"]:
        print(f"magbench: warning: {warning}", file=sys.stderr)
