"""The wheel carries every package and the configuration (an installed magbench finds conf/)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def test_every_package_is_listed_for_the_wheel():
    setup = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    on_disk = {".".join(p.parent.relative_to(REPO / "src").parts)
               for p in (REPO / "src").rglob("__init__.py")}
    conf = {"magbench.conf"} | {f"magbench.conf.{d.name}" for d in (REPO / "conf").iterdir()
                                if d.is_dir()}
    assert set(setup["packages"]) == on_disk | conf
    assert setup["package-dir"]["magbench.conf"] == "conf"


def test_the_configuration_is_package_data():
    data = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"]
    for package in ("magbench.conf", "magbench.conf.sweep"):
        folder = REPO / package.replace("magbench.conf", "conf").replace(".", "/")
        assert data[package] == ["*.yaml"] and list(folder.glob("*.yaml"))


# CI installs the package as the README does (editable); the built wheel's package data are
# checked above without a build, the wheel itself in make test-all.
@pytest.mark.slow
def test_a_built_wheel_runs_a_sweep_from_another_folder(tmp_path):
    """A non-editable install (the wheel, not src/) finds its configs from any folder."""
    pip = [sys.executable, "-m", "pip"]
    # Build from a copy: setuptools writes build/ and *.egg-info beside the sources.
    source = tmp_path / "source"
    skip = shutil.ignore_patterns("__pycache__", "*.egg-info", "build")
    for part in ("src", "conf"):
        shutil.copytree(REPO / part, source / part, ignore=skip)
    for part in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / part, source / part)
    built = subprocess.run([*pip, "wheel", "-q", "--no-deps", "-w", str(tmp_path / "w"),
                            str(source)], capture_output=True, text=True, timeout=300)
    if built.returncode != 0 and any(s in built.stderr.lower() for s in
                                     ("connection", "could not find a version", "network")):
        pytest.skip("building the wheel needs setuptools from the package index")
    assert built.returncode == 0, built.stderr[-2000:]
    wheel = next((tmp_path / "w").glob("magbench-*.whl"))
    site = tmp_path / "site"
    subprocess.run([*pip, "install", "-q", "--no-deps", "--target", str(site), str(wheel)],
                   check=True, capture_output=True, timeout=300)
    away = tmp_path / "elsewhere"
    away.mkdir()
    env = {**os.environ, "PYTHONPATH": str(site)}
    probe = subprocess.run([sys.executable, "-c", "import magbench; print(magbench.__file__)"],
                           cwd=away, env=env, capture_output=True, text=True, check=True)
    assert Path(probe.stdout.strip()).is_relative_to(site)  # the wheel's copy, not src/
    run = subprocess.run([sys.executable, "-m", "magbench", "sweep=baseline", "trials=2",
                          "algorithms=[sphere]", "n_jobs=1", "progress=false",
                          f"results_dir={tmp_path / 'r'}"],
                         cwd=away, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "r" / "baseline" / "trials.csv").is_file()


def test_the_report_templates_are_package_data():
    data = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"]
    assert "report/templates/*.md" in data["magbench"]
    assert list((REPO / "src" / "magbench" / "report" / "templates").glob("*.md"))
