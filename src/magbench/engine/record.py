"""``run.json``: what produced a result folder (versions, machine, config, timing)."""

from __future__ import annotations

import hashlib
import json
import os
import platform
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from magbench.core.files import write_text_atomic

__all__ = ["cpu_model", "cpu_seconds", "fit_module", "git_commit", "method_code",
           "method_modules", "package_versions", "process_age_s", "study_code",
           "write_run_record"]

#: The package whose modules count as a method's code (besides the method's own module).
METHODS_PACKAGE = "magbench.methods.algorithms"

PACKAGES = ("magbench", "numpy", "scipy", "pandas", "matplotlib", "joblib", "hydra-core",
            "numba", "dask", "distributed")


def cpu_model() -> str:
    """The CPU model name (``/proc/cpuinfo``; ``platform.processor()`` elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _proc_cpu_ticks(stat: str) -> tuple[int, int]:
    """``(ppid, utime + stime + cutime + cstime)`` from the text of ``/proc/<pid>/stat``.

    The command name (field 2) may hold spaces and parentheses, so the fields are counted from
    its closing parenthesis: state, ppid, ..., utime (14), stime, cutime, cstime (17).
    """
    fields = stat[stat.rindex(")") + 2:].split()
    return int(fields[1]), sum(int(v) for v in fields[11:15])


def cpu_seconds() -> float:
    """CPU time (user + system, seconds) of this process and all its descendants so far.

    Finished descendants count through ``getrusage(RUSAGE_CHILDREN)`` once waited for; live
    ones, such as joblib's worker pool, which outlives each sweep, are read from ``/proc``
    (Linux; elsewhere only this process and finished children are counted). The difference of
    two calls is the CPU time spent in between, workers included.
    """
    import resource  # here: POSIX only, and nothing that imports the engine needs it

    own = resource.getrusage(resource.RUSAGE_SELF)
    done = resource.getrusage(resource.RUSAGE_CHILDREN)
    total = own.ru_utime + own.ru_stime + done.ru_utime + done.ru_stime
    proc = Path("/proc")
    if not (proc / "self" / "stat").exists():
        return total
    parents, ticks = {}, {}
    for stat in proc.glob("[0-9]*/stat"):
        try:
            parents[int(stat.parent.name)], ticks[int(stat.parent.name)] = \
                _proc_cpu_ticks(stat.read_text())
        except (OSError, ValueError, IndexError):
            continue  # the process ended while the table was read
    live, frontier = set(), {os.getpid()}
    while frontier:
        frontier = {pid for pid, ppid in parents.items() if ppid in frontier} - live
        live |= frontier
    return total + sum(ticks[pid] for pid in live) / os.sysconf("SC_CLK_TCK")


def process_age_s() -> float:
    """Wall time since this process started (``/proc``; NaN where it cannot be read): the
    interpreter's start-up and imports, which a timer started in Python misses."""
    try:
        stat = Path("/proc/self/stat").read_text()
        started = int(stat[stat.rindex(")") + 2:].split()[19]) / os.sysconf("SC_CLK_TCK")
        return float(Path("/proc/uptime").read_text().split()[0]) - started
    except (OSError, ValueError, IndexError):
        return float("nan")


def git_commit() -> str:
    """The git commit of the magbench source tree (``+dirty`` with local changes), or ''."""
    root = Path(__file__).resolve().parents[3]
    if not (root / ".git").exists():
        return ""
    try:
        commit = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"],
                                capture_output=True, text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--", "src"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""
    return commit + ("+dirty" if commit and dirty else "")


def package_versions() -> dict[str, str]:
    """Installed versions of magbench and the packages that shape its numbers."""
    from importlib import metadata  # here: 10 ms of import that calibrate does not need

    out = {"python": sys.version.split()[0]}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return out


#: Parsed sources by path: (size, mtime in ns) when read, the bytes, the modules imported.
#: A sweep hashes the same files for each of its methods; an edited file is read again.
_SOURCES: dict[str, tuple[tuple[int, int], bytes, set[str]]] = {}


def _module_origin(name: str) -> str | None:
    """The source file of module ``name`` (None when it has none)."""
    import importlib.util

    module = sys.modules.get(name)
    origin = getattr(module, "__file__", None)
    if origin is None:
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            return None
        origin = spec.origin if spec is not None else None
    return origin if origin and str(origin).endswith(".py") else None


def _module_source(name: str) -> tuple[bytes, set[str]] | None:
    """The source bytes of module ``name`` and the modules it imports (None when it has no
    source file)."""
    origin = _module_origin(name)
    if origin is None:
        return None
    try:
        stat = os.stat(origin)
        key = (stat.st_size, stat.st_mtime_ns)
        found = _SOURCES.get(origin)
        if found is None or found[0] != key:
            source = Path(origin).read_bytes()
            found = (key, source, _imported_modules(name, source))
            _SOURCES[origin] = found
    except OSError:
        return None
    return found[1], found[2]


def _imported_modules(name: str, source: bytes) -> set[str]:
    """The modules ``source`` (module ``name``) imports, absolute names, relative resolved."""
    import ast

    try:
        tree = ast.parse(source)
    except SyntaxError:
        return set()
    package = name.rsplit(".", 1)[0]
    if name.endswith(".__init__"):
        package = name
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[:len(parts) - node.level + 1]
                base = ".".join([*parts, base] if base else parts)
            found.add(base)
            # ``from pkg import module``: the names may be modules themselves.
            found.update(f"{base}.{alias.name}" for alias in node.names)
    return found


def fit_module(fit: object) -> str:
    """The module that defines a method's ``fit`` (through any ``functools.partial``, which a
    variant of a method registers)."""
    import functools

    while isinstance(fit, functools.partial):
        fit = fit.func
    return str(getattr(fit, "__module__", "") or "")


def method_modules(module: str) -> dict[str, bytes]:
    """Module ``module`` and every module of :data:`METHODS_PACKAGE` it imports, directly or
    through those, with their source bytes as they are on disk now."""
    return _modules(module, lambda m: m.startswith(METHODS_PACKAGE + "."))


def _modules(module: str, follow: Callable[[str], bool]) -> dict[str, bytes]:
    """``module`` and the modules it imports for which ``follow`` is true, transitively,
    with their source bytes."""
    seen: dict[str, bytes] = {}
    todo = [module]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        found = _module_source(name)
        if found is None:
            if name == module:
                seen[name] = b""
            continue
        seen[name], imported = found
        todo.extend(m for m in imported if follow(m) and m not in seen)
    return seen


def study_code(module: str) -> str:
    """SHA-256 (16 hex digits) of a study's code: its module ``module`` and every ``magbench``
    module it imports, directly or through those, except the methods' own
    (:data:`METHODS_PACKAGE`, keyed per method by :func:`method_code`). An edit to the data
    generation, the metrics, the trial loop or the engine changes it, and every row of the
    study is recomputed."""
    return _code_hash(_modules(module, lambda m: m.startswith("magbench.")
                               and not m.startswith(METHODS_PACKAGE + ".")))


def _code_hash(sources: dict[str, bytes]) -> str:
    digest = hashlib.sha256()
    for name in sorted(sources):
        digest.update(name.encode() + b"\0" + hashlib.sha256(sources[name]).digest())
    return digest.hexdigest()[:16]


def method_code(module: str) -> str:
    """SHA-256 (16 hex digits) of the code that computes a method's rows: the source of its
    module ``module`` and of every module of :data:`METHODS_PACKAGE` it imports
    (:func:`method_modules`).

    An edit to any of these files changes the hash, so rows a method computed before the edit
    are recomputed rather than reused; code outside them (NumPy, ``magbench.core``) is not
    followed. A module without a source file hashes to its name alone.
    """
    return _code_hash(method_modules(module))


def write_run_record(out_dir: Path | str, **fields: object) -> Path:
    """Write ``<out_dir>/run.json``: version, commit, packages, CPU and ``fields``."""
    record = {"magbench_version": package_versions().get("magbench", ""),
              "git_commit": git_commit(), "packages": package_versions(),
              "cpu_model": cpu_model(), "cpu_count": os.cpu_count(),
              "platform": platform.platform(), **fields}
    path = Path(out_dir) / "run.json"
    write_text_atomic(json.dumps(record, indent=2, sort_keys=False, default=str) + "\n", path)
    return path
