"""Entry point: a small argument layer over Hydra's compose API, with help that explains it.

``python -m magbench [COMMAND] [key=value ...]``; COMMAND defaults to ``run``. Every command
takes ``--help``; keys are plain ``key=value`` Hydra overrides (``options.<method>.<name>=...``
needs no ``+``).
"""

from __future__ import annotations

import os
import re
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from magbench.cli.process import configure_process

# Only the standard library at import: ``calibrate`` starts its picture process
# (:mod:`magbench.cli.picture`) before the configuration, NumPy and pandas are loaded.
if TYPE_CHECKING:
    from omegaconf import DictConfig

    from magbench.cli.picture import PictureWorker

__all__ = ["COMMANDS", "INTERRUPTED", "main"]

#: The one line a Ctrl-C prints, whenever it comes.
INTERRUPTED = "magbench: interrupted; finished chunks are kept and a rerun completes the rest"


def _run(cfg: DictConfig) -> int:
    from magbench.cli.commands import run

    return run(cfg)


def _bench(cfg: DictConfig) -> int:
    from magbench.cli.commands import bench

    return bench(cfg)


def _reproduce(overrides: Sequence[str]) -> int:
    from magbench.cli.commands import reproduce

    return reproduce(overrides)


def _report(cfg: DictConfig) -> int:
    from magbench.cli.commands import report

    return report(cfg)


def _calibrate(cfg: DictConfig, picture: PictureWorker | None = None) -> int:
    from magbench.cli.calibrate import run_calibrate

    return run_calibrate(cfg, picture=picture)


def _capture(cfg: DictConfig) -> int:
    from magbench.cli.capture import run_capture

    return run_capture(cfg)


def _apply(cfg: DictConfig) -> int:
    from magbench.cli.apply import run_apply

    return run_apply(cfg)


def _extract(cfg: DictConfig) -> int:
    from magbench.cli.extract import run_extract

    return run_extract(cfg)


def _warmup(cfg: DictConfig) -> int:
    from magbench.cli.warmup import run_warmup

    return run_warmup(cfg)


def _methods(cfg: DictConfig) -> int:
    from magbench.cli.config import check_common

    check_common(cfg)               # loads plugins=[...], so their methods are listed too
    print(methods_table())
    return 0


#: command -> (function, one line, example, the config keys it reads); every function takes the
#: composed config except ``reproduce``'s, which composes one per sweep from the overrides.
COMMANDS: dict[str, tuple[Callable[..., int], str, str, tuple[str, ...]]] = {
    "run": (_run, "run one sweep (the default command)",
            "python -m magbench sweep=gamma trials=20 results_dir=/tmp/try",
            ("sweep", "trials", "seed", "n_jobs", "chunk_size", "algorithms", "options", "delta",
             "results_dir", "progress", "call_timeout_s", "plugins", "backend",
             "scheduler_address", "nominal", "data_dir")),
    "calibrate": (_calibrate, "calibrate your own recording and write the correction",
                  "python -m magbench calibrate file=data.csv",
                  ("file", "method", "candidates", "columns", "out", "preprocess",
                   "max_samples", "compensate", "bootstrap", "seed", "units", "field_strength",
                   "location", "date", "gate", "instance", "overwrite", "picture",
                   "options", "call_timeout_s", "plugins")),
    "capture": (_capture, "record a live stream with a coverage view, stop when enough, "
                "calibrate it", "python -m magbench capture port=/dev/ttyACM0 out=cal/",
                ("port", "baud", "format", "rate", "stop", "out", "units", "columns",
                 "instance", "gate", "overwrite", "method", "candidates", "picture",
                 "field_strength", "location", "date", "plugins")),
    "apply": (_apply, "correct a recording with a saved calibration.json (m = A (y - b))",
              "python -m magbench apply calibration=cal/calibration.json file=flight.csv "
              "out=flight-corrected.csv", ("calibration", "file", "columns", "instance", "out",
                                            "overwrite")),
    "extract": (_extract, "write a flight log's compass and its other streams, time-aligned, "
                "as CSV (PX4 .ulg, ArduPilot .bin/.log)",
                "python -m magbench extract file=flight.ulg instance=0 out=data.csv",
                ("file", "instance", "out", "overwrite")),
    "reproduce": (_reproduce, "every sweep at its committed size, then the report (make "
                  "reproduce); per-step times to results/bench/reproduce_times.csv",
                  "python -m magbench reproduce",
                  ("results_dir", "n_jobs", "progress", "data_dir")),
    "report": (_report, "redraw every figure and rewrite results/report.md from the CSV files",
               "python -m magbench report", ("results_dir", "n_jobs")),
    "bench": (_bench, "time every method, its scaling with K, peers and parallel speed-up",
              "python -m magbench bench", ("results_dir", "algorithms", "progress",
                                           "timing_check", "sweep", "scale", "n_jobs")),
    "methods": (_methods, "list the registered calibration methods and their options",
                "python -m magbench methods", ("plugins",)),
    "warmup": (_warmup, "compile the methods' numba loops now (a first run does it itself)",
               "python -m magbench warmup", ("algorithms", "plugins", "progress")),
}


#: What ``calibrate`` does, for its --help (docs/calibrate.md says it at length).
CALIBRATE_STEPS = [
    "reads the file (CSV, .ulg, .bin, .log) -> thins still stretches and sets outliers aside ->",
    "fits the candidates on all samples and on interleaved time-block folds -> chooses the",
    "simplest of those tied out of sample -> judges it PASS / WARN / FAIL (gate.*; a field",
    "strength the Earth does not give in units= fails) -> writes out/ as one folder:",
    "calibration.json (m = A (y - b)), calibration.h, ardupilot.param and px4.params (a",
    "known or inferred unit), inav.txt and betaflight.txt (units=counts), ranking.csv,",
    "calibration.png and manifest.json. Exit 0 PASS or WARN, 3 FAIL (the reasons, no",
    "correction), 2 a bad input or a folder in use. Details: docs/calibrate.md.", ""]


def _key_help() -> dict[str, tuple[str, str]]:
    """``key -> (default, meaning)`` from the comments of ``conf/config.yaml``; the keys of a
    section (``gate:``) as ``gate.<key>``."""
    from magbench.cli.config import config_dir

    out, section = {}, None
    for line in (config_dir() / "config.yaml").read_text().splitlines():
        match = re.match(r"^( *)([A-Za-z_]+):\s*([^#]*?)\s*(?:#\s*(.*))?$", line)
        if not match or match.group(2) == "defaults":
            continue
        indent, key, default, meaning = match.groups()
        if not indent:
            section = key if not default else None
            out[key] = (default, meaning or "")
        elif section is not None:
            out[f"{section}.{key}"] = (default, meaning or "")
    return out


def sweep_kinds() -> list[tuple[str, str]]:
    """``(name, first comment line)`` of every ``conf/sweep/*.yaml``."""
    from magbench.cli.config import config_dir

    out = []
    for path in sorted((config_dir() / "sweep").glob("*.yaml")):
        out.append((path.stem, _first_sentence(path.read_text())))
    return out


def _first_sentence(text: str) -> str:
    """The leading comment's first sentence, joined across lines (never cut mid-sentence: a
    sentence ends at . ? or ! before a capital letter or at the comment's end)."""
    words = []
    for line in text.splitlines():
        if not line.startswith("#"):
            break
        if "@package" not in line:
            words.append(line.lstrip("# ").strip())
    joined = " ".join(w for w in words if w)
    return re.split(r"(?<=[.?!])\s+(?=[A-Z])", joined, maxsplit=1)[0]


def kind_keys_help() -> list[str]:
    """The ``sweep.*`` keys of every registered study kind: default and meaning."""
    from magbench.cli.kinds import get_kind, kind_names

    lines = ["sweep keys by kind (sweep.<key>=value; default, meaning):"]
    for name in kind_names():
        kind = get_kind(name)
        lines.append(f"  {name}: {kind.what}")
        lines += [f"    {k.name:<16} {_short(k.default):<22} {k.meaning}" for k in kind.keys]
    return lines


def _short(value: object, width: int = 22) -> str:
    text = str(value).replace("'", "")
    return text if len(text) <= width else text[:width - 3] + "..."


def methods_table() -> str:
    """The registry as text: name, label, family, gyro, minimum K, options and defaults."""
    import inspect

    from magbench.methods.registry import get_method, methods

    names = methods()
    # Columns as wide as their longest entry: a label is never cut.
    wn = max(len(n) for n in names) + 2
    wl = max(len(get_method(n).label) for n in names) + 2
    lines = [f"{'name':<{wn}}{'label':<{wl}}{'family':<9}{'gyro':<6}{'min K':<7}"
             "options (defaults)"]
    for name in names:
        spec = get_method(name)
        params = inspect.signature(spec.fit).parameters
        opts = ", ".join(f"{o}={params[o].default!r}" if params[o].default is not
                         inspect.Parameter.empty else o for o in spec.option_names()
                         if o not in ("angular_rate", "time", "acceleration"))
        ref = f" [Table 2: {spec.paper_key}]" if spec.paper_key else ""
        ref += " [needs an accelerometer; heading-true]" if spec.needs_accel else ""
        lines.append(f"{name:<{wn}}{spec.label:<{wl}}{spec.family:<9}"
                     f"{'yes' if spec.needs_gyro else 'no':<6}{spec.min_samples:<7}"
                     f"{opts or '-'}{ref}")
    return "\n".join(lines)


def general_help() -> str:
    from magbench import __version__

    lines = [f"magbench {__version__}: Monte Carlo benchmark of three-axis magnetometer "
             "calibration", "", "usage: python -m magbench [COMMAND] [key=value ...]", "",
             "commands:"]
    for name, (_, what, example, _) in COMMANDS.items():
        lines.append(f"  {name:<10} {what}")
        lines.append(f"  {'':<10}   e.g. {example}")
    lines += ["", "sweeps (run sweep=NAME):"]
    lines += [f"  {name:<10} {what}" for name, what in sweep_kinds()]
    lines += ["", "python -m magbench COMMAND --help lists the keys a command reads; "
              "python -m magbench methods lists the methods; --version prints the version."]
    return "\n".join(lines)


def command_help(command: str) -> str:
    _, what, example, keys = COMMANDS[command]
    known = _key_help()
    lines = [f"python -m magbench {command} [key=value ...]: {what}", f"example: {example}", ""]
    if command == "calibrate":
        lines += CALIBRATE_STEPS
    lines.append("keys (default, meaning):")
    for key in keys:
        default, meaning = known.get(key, ("", ""))
        if key == "sweep":
            default, meaning = "baseline", ("with timing_check=true: the sweep whose timing "
                                            "pass is run twice" if command == "bench" else
                                            "which sweep to run (see below)")
        if key == "nominal":
            default, meaning = "K=300 sigma=0.005 beta=0.05 gamma=0.05", \
                "the nominal point of eq. (80), e.g. nominal.K=150"
        if key == "options":
            default, meaning = "{}", "a method's option, e.g. options.magical.max_iter=100"
        lines.append(f"  {key:<21} {default:<22} {meaning}")
        lines += [f"  {sub:<21} {d:<22} {m}" for sub, (d, m) in known.items()
                  if sub.startswith(f"{key}.") and key not in ("nominal", "options")]
    if "sweep" in keys:
        lines += ["", "sweeps:"] + [f"  {n:<10} {w}" for n, w in sweep_kinds()]
    if command == "run":
        lines += ["", *kind_keys_help()]
    if command in ("run", "calibrate", "capture", "bench", "warmup"):
        from magbench.methods.registry import methods

        lines += ["", "methods (algorithms=[...] or method=NAME; details: python -m "
                  "magbench methods):", "  " + ", ".join(methods())]
    return "\n".join(lines)


def _plain_keys(args: list[str]) -> list[str]:
    """Hydra overrides from plain keys: ``options.<method>.<name>=v`` adds a key Hydra does not
    know yet, so it is force-added (``++``); a ``+`` before a key the config already has (an
    older habit, ``+preprocess=scale``) is dropped."""
    known = set(_key_help())
    out = []
    for arg in args:
        bare = arg.lstrip("+")
        if bare.startswith(("options.", "sweep.")):
            # Added if new, so that a misspelt sweep key reaches the kind's check, which names
            # the keys it reads, instead of Hydra's advice to add it with '+'.
            out.append(f"++{bare}")
        elif _bare_list(bare):
            # ``location=52.5,13.4`` as --help writes it: Hydra calls a bare comma list
            # ambiguous (a sweep or a list); these keys only take lists.
            key, value = bare.split("=", 1)
            out.append(f"{key}=[{value}]")
        elif arg.startswith("+") and not arg.startswith("++") and \
                bare.split("=", 1)[0].split(".", 1)[0] in known:
            out.append(bare)
        else:
            out.append(arg)
    return out


#: Keys whose value is a list, so that ``key=a,b`` means ``key=[a,b]``.
LIST_KEYS = ("location", "columns", "candidates", "algorithms", "compensate", "plugins")


def _bare_list(arg: str) -> bool:
    key, _, value = arg.partition("=")
    return key in LIST_KEYS and "," in value and not value.startswith(("[", "'", '"'))


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m magbench`` and the ``magbench`` script.

    Called as a process's entry point (``argv`` None: the arguments are ``sys.argv``), it makes
    the process settings first (:func:`~magbench.cli.process.configure_process`: one BLAS
    thread, glibc's malloc thresholds). Called with ``argv`` (tests, a host program), it
    changes none of them. Returns the exit status.
    """
    if argv is None:
        configure_process()       # BLAS threads and malloc, before NumPy is imported
    try:
        code = _main(argv)
    except BrokenPipeError:
        # The reader went away (``magbench methods | head``): not an error worth a traceback.
        # Point stdout at /dev/null so the interpreter's final flush cannot raise again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        code = 128 + signal.SIGPIPE
    except KeyboardInterrupt:       # a Ctrl-C before or after the command's own handling
        print(INTERRUPTED, file=sys.stderr)
        code = 130
    return code


def _start_picture() -> PictureWorker | None:
    from magbench.cli.picture import PictureWorker

    return PictureWorker.start()


def _main(argv: Sequence[str] | None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] in ("--version", "-V", "version"):
        from magbench import __version__

        print(f"magbench {__version__}")
        return 0
    if args and args[0] in ("-h", "--help", "help"):
        print(general_help())
        return 0
    command = args.pop(0) if args and args[0] in COMMANDS else "run"
    if any(a in ("-h", "--help") for a in args):
        print(command_help(command))
        return 0
    bad = [a for a in args if "=" not in a]
    if bad:
        from magbench.cli.config import did_you_mean

        guess = did_you_mean(bad[0], list(COMMANDS))
        hint = f" (did you mean {guess}?)" if guess else ""
        print(f"magbench: error: unknown command or argument {bad[0]!r}{hint}; expected one of "
              f"{', '.join(COMMANDS)} followed by key=value pairs (python -m magbench --help)",
              file=sys.stderr)
        return 2
    # Started first, so that the picture process imports matplotlib while this one loads the
    # configuration and fits; closed (stopped, if it was never given a picture) at the end.
    picture = (_start_picture() if command == "calibrate"
               and not any(a.lstrip("+").lower() == "picture=false" for a in args) else None)
    try:
        return _dispatch(command, args, picture)
    finally:
        if picture is not None:
            picture.close()


def _dispatch(command: str, args: list[str], picture: PictureWorker | None) -> int:
    from magbench.cli.config import UsageError, compose_config
    from magbench.engine.isolation import WorkerDied
    from magbench.engine.sweep import FolderBusy, ResultsExist, TooLarge

    previous = signal.signal(signal.SIGTERM, _terminate) if _main_thread() else None
    try:
        if command == "reproduce":
            return _reproduce(_plain_keys(args))
        cfg = compose_config(_plain_keys(args))
        if picture is not None:
            return _calibrate(cfg, picture)
        return COMMANDS[command][0](cfg)
    except (UsageError, FolderBusy, ResultsExist, TooLarge) as exc:
        print(f"magbench: error: {exc}", file=sys.stderr)
        return 2
    except WorkerDied as exc:
        # Not the user's input: a unit's own code (outside any method call) killed its
        # process. One line and a failing status; finished chunks are kept.
        print(f"magbench: error: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:
        raise                       # the reader went away: main() ends quietly
    except OSError as exc:
        # A file-system refusal the checks could not foresee (a disk that fills, a folder
        # removed under a run): one line naming the path, not a traceback.
        where = f" ({exc.filename})" if exc.filename else ""
        print(f"magbench: error: {exc.strerror or exc}{where}; check that the paths given "
              "exist, are of the right kind and can be written", file=sys.stderr)
        return 2
    except KeyboardInterrupt as stop:
        what = "terminated" if isinstance(stop, Terminated) else "interrupted"
        print(INTERRUPTED.replace("interrupted", what), file=sys.stderr)
        return 143 if isinstance(stop, Terminated) else 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled as Ctrl-C is: finished chunks are kept, one line, exit 143."""


def _terminate(signum: int, frame: object) -> None:
    raise Terminated


def _main_thread() -> bool:
    # signal.signal works only in the main thread (a host application may call main elsewhere).
    return threading.current_thread() is threading.main_thread()
