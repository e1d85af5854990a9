"""The wheel carries every package and the configuration (an installed magbench finds conf/)."""

from __future__ import annotations

import tomllib
from pathlib import Path

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
