"""``run.json``: what produced a result folder (versions, machine, config, timing)."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path

from magbench.core.files import write_text_atomic

__all__ = ["cpu_model", "git_commit", "package_versions", "write_run_record"]

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
    out = {"python": sys.version.split()[0]}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return out


def write_run_record(out_dir: Path | str, **fields: object) -> Path:
    """Write ``<out_dir>/run.json``: version, commit, packages, CPU and ``fields``."""
    record = {"magbench_version": package_versions().get("magbench", ""),
              "git_commit": git_commit(), "packages": package_versions(),
              "cpu_model": cpu_model(), "cpu_count": os.cpu_count(),
              "platform": platform.platform(), **fields}
    path = Path(out_dir) / "run.json"
    write_text_atomic(json.dumps(record, indent=2, sort_keys=False, default=str) + "\n", path)
    return path
