"""Study kinds are registered like methods: a new kind is one module plus its conf file, and
every kind's defaults agree across its Keys, its study dataclass and its conf file."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path
from typing import ClassVar

import matplotlib.pyplot as plt
import pandas as pd
import pytest
import yaml

from magbench.cli import main
from magbench.cli.config import Key, config_dir, field_default, integer
from magbench.cli.kinds import Kind, get_kind, kind_names, register_kind, unregister_kind
from magbench.engine.sweep import Study
from magbench.figures.style import save_figure

# --- a toy kind, declared in this one module -------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ToyStudy(Study):
    trials: int
    seed: int
    squares: int = 3
    plugins: tuple = ()
    name: str = "toy"

    tables: ClassVar[dict] = {"trials": ("trials.csv", ["unit", "value", "ok"])}

    def units(self) -> list[int]:
        return list(range(self.trials))

    def run_unit(self, unit: int) -> dict[str, list[dict]]:
        return {"trials": [{"unit": unit, "value": (unit + self.seed) ** 2, "ok": True}]}


def _finish(study: ToyStudy, out_dir: Path, common: dict) -> None:
    trials = pd.read_csv(out_dir / "trials.csv")
    pd.DataFrame({"total": [trials["value"].sum()]}).to_csv(out_dir / "summary.csv",
                                                            index=False)


def _figures(name: str, out_dir: Path) -> list[Path]:
    fig, ax = plt.subplots()
    ax.plot(pd.read_csv(out_dir / "trials.csv")["value"])
    return [save_figure(fig, out_dir / "toy.png")]


def _report(results_dir: Path) -> str:
    path = results_dir / "toy" / "summary.csv"
    return f"## Toy\n\ntotal {int(pd.read_csv(path)['total'][0])}" if path.exists() else ""


TOY = Kind(name="toy", what="a toy kind for the tests",
           keys=(Key("squares", field_default(ToyStudy, "squares"), "how many", integer(1)),),
           build=lambda cfg, common, values: ToyStudy(int(cfg.trials), common["seed"],
                                                      values["squares"]),
           finish=_finish, figures=_figures, report=_report)


@pytest.fixture
def toy_conf(tmp_path, monkeypatch):
    """A copy of conf/ with the toy's conf file, and the toy registered; both undone after."""
    conf = tmp_path / "conf"
    shutil.copytree(config_dir(), conf)
    (conf / "sweep" / "toy.yaml").write_text(
        "# @package _global_\n# A toy sweep.\ntrials: 4\nsweep:\n  name: toy\n  kind: toy\n"
        "  vary: null\n  values: []\n  squares: 3\n")
    monkeypatch.setenv("MAGBENCH_CONF", str(conf))
    register_kind(TOY)
    yield conf
    unregister_kind("toy")


def test_a_kind_from_one_module_runs_draws_and_reports(toy_conf, tmp_path, capsys):
    results = tmp_path / "results"
    assert main(["sweep=toy", "seed=1", "n_jobs=1", "progress=false",
                 f"results_dir={results}"]) == 0
    trials = pd.read_csv(results / "toy" / "trials.csv")
    assert list(trials["value"]) == [1, 4, 9, 16]
    assert (results / "toy" / "toy.png").exists()
    assert main(["report", f"results_dir={results}"]) == 0
    assert "## Toy\n\ntotal 30" in (results / "report.md").read_text()
    assert "toy" in capsys.readouterr().out
    unregister_kind("toy")
    assert "toy" not in kind_names()


def test_a_kind_refuses_a_misspelt_key_with_a_suggestion(toy_conf, tmp_path, capsys):
    assert main(["sweep=toy", "sweep.sqares=2", f"results_dir={tmp_path}"]) == 2
    assert "(did you mean sweep.squares?)" in capsys.readouterr().err


def test_an_unknown_kind_names_the_registered_ones(toy_conf, tmp_path, capsys):
    (toy_conf / "sweep" / "odd.yaml").write_text(
        "# @package _global_\nsweep:\n  name: odd\n  kind: tyo\n  vary: null\n  values: []\n")
    assert main(["sweep=odd", f"results_dir={tmp_path}"]) == 2
    err = capsys.readouterr().err
    assert "sweep.kind must be one of" in err and "(did you mean 'toy'?)" in err


def test_no_kind_test_outside_the_kinds_modules():
    src = Path(__file__).resolve().parents[2] / "src" / "magbench"
    hits = [p for p in src.rglob("*.py") if "kinds" not in p.parts and
            ('kind == "' in p.read_text() or "kind != \"" in p.read_text())]
    assert hits == []


# --- one source of defaults ------------------------------------------------------------------


def _plain(value: object) -> object:
    """Tuples as lists, recursively (YAML has no tuples)."""
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _sweep_section(name: str) -> dict:
    data = yaml.safe_load((config_dir() / "sweep" / f"{name}.yaml").read_text()) or {}
    return data["sweep"] if isinstance(data.get("sweep"), dict) else data


@pytest.mark.parametrize("name", ["gyro", "real", "wushi", "heading"])
def test_a_kinds_conf_file_lists_every_key_at_its_default(name):
    kind = get_kind(name)
    section = _sweep_section(name)
    assert {k: _plain(section[k]) for k in kind.key_names()} == \
        {k.name: _plain(k.default) for k in kind.keys}
    assert set(section) == {"name", "kind", "vary", "values", *kind.key_names()}


@pytest.mark.parametrize(("name", "study"), [("gyro", "magbench.studies.gyro:GyroStudy"),
                                             ("real", "magbench.studies.real:RealStudy"),
                                             ("wushi", "magbench.studies.wushi:WuShiStudy")])
def test_the_study_dataclass_defaults_are_the_keys_defaults(name, study):
    import importlib

    module, cls = study.split(":")
    fields = {f.name for f in dataclasses.fields(getattr(importlib.import_module(module), cls))
              if f.default is not dataclasses.MISSING
              or f.default_factory is not dataclasses.MISSING}
    shared = [k for k in get_kind(name).keys if k.name in fields]
    assert shared
    for key in shared:
        assert _plain(field_default(getattr(importlib.import_module(module), cls), key.name)) \
            == _plain(key.default), key.name


def test_every_sweep_conf_uses_only_its_kinds_keys():
    for path in sorted((config_dir() / "sweep").glob("*.yaml")):
        section = _sweep_section(path.stem)
        kind = get_kind(str(section.get("kind", "review")))
        assert set(section) <= {"name", "kind", "vary", "values", *kind.key_names()}, path


def test_the_readme_key_table_agrees_with_conf():
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    base = yaml.safe_load((config_dir() / "config.yaml").read_text())
    rows = [line.split("|")[1:4] for line in readme.splitlines()
            if line.startswith("| `") and line.count("|") == 4]
    checked = 0
    for key, _, default in rows:
        key, default = key.strip().strip("`"), default.strip().strip("`")
        if key in base and not isinstance(base[key], dict):
            value = base[key]
            expected = str(value).lower() if isinstance(value, bool) else \
                "[]" if value == [] else "null" if value is None else str(value)
            assert default == expected, key
            checked += 1
    assert checked >= 8
