"""Every example in README.md, docs/calibrate.md and docs/flight_logs.md runs and prints what
the page shows.

Two kinds of example are checked:

* a transcript, a fenced block whose lines start with ``$ python -m magbench ...`` followed by
  what it prints (stdout, then stderr): each command is run and its output compared;
* an output block preceded by ``<!-- output of: ARGS -->``: ``python -m magbench ARGS`` is run
  and its stdout compared.

Paths as the pages write them (``../shared/data/real``, ``../shared/data/logs``, ``/tmp/NAME``,
a bare ``flight.ulg``) are mapped to the shared data and to a fresh folder; the run time
``(in 0.69 s)`` is compared as ``(in N s)``. ``MAGBENCH_UPDATE_DOCS=1 python -m pytest
tests/cli/test_docs_examples.py -m ''`` rewrites the pages from real runs instead.

The ``python -m magbench`` lines of the pages' ``bash`` blocks that take the user's own file
(``my_log.csv``, ``flight.csv``) are run on a synthetic recording and must exit 0.
"""

from __future__ import annotations

import os
import re
import shlex
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from magbench.cli import main
from magbench.core.geometry import fibonacci_sphere

ROOT = Path(__file__).resolve().parents[2]
PAGES = ("README.md", "docs/calibrate.md", "docs/flight_logs.md")
DATA = os.environ.get("MAGBENCH_DATA")
LOGS = str(Path(DATA).parent / "logs") if DATA else None
UPDATE = os.environ.get("MAGBENCH_UPDATE_DOCS") == "1"
MARK = re.compile(r"<!-- output of: (.*?) -->\n+```[a-z]*\n(.*?)```", re.S)
FENCE = re.compile(r"```[a-z]*\n(.*?)```", re.S)
#: The simulated log of docs/flight_logs.md, as its ``python -c`` line makes it.
FLIGHT = ("from pathlib import Path; import numpy as np; from tests.pipeline.test_flight import "
          "simulated_ulog; simulated_ulog(Path('flight.ulg'), 6, seed=4, seconds=60, "
          "motor=np.array([0.004, -0.002, 0.003]))")


def _normal(text: str) -> str:
    text = re.sub(r"\(in [\d.]+ s\)", "(in N s)", text)
    return "\n".join(line.rstrip() for line in text.strip().splitlines())


def _args(command: str, where: Path) -> tuple[list[str], dict[str, str]]:
    """magbench's arguments of a page's command, with the page's paths mapped; and the map
    back from the real paths to the page's."""
    back = {}
    args = []
    for arg in shlex.split(command):
        new = arg
        if DATA:
            new = new.replace("../shared/data/real", DATA).replace("../shared/data/logs", LOGS)
        for name in re.findall(r"/tmp/[\w.-]+", arg):
            real = str(where / name.removeprefix("/tmp/"))
            new = new.replace(name, real)
            back[real] = name
        args.append(new)
    return args, back


def _run(command: str, where: Path, capsys) -> tuple[str, str]:
    args, back = _args(command, where)
    if "flight.ulg" in command and not (where / "flight.ulg").exists():
        exec(FLIGHT, {})
    capsys.readouterr()
    main(args)
    out, err = capsys.readouterr()
    for real, shown in back.items():
        out, err = out.replace(real, shown), err.replace(real, shown)
    if LOGS:
        err = err.replace(LOGS, "../shared/data/logs")
    return out, err


def _examples() -> list[tuple[str, str, str, str]]:
    """(page, kind, command, shown) of every checked example."""
    found = []
    for page in PAGES:
        text = (ROOT / page).read_text()
        for command, shown in MARK.findall(text):
            found.append((page, "output", command, shown))
        for block in FENCE.findall(text):
            if block.startswith("$ python -m magbench"):
                found.append((page, "transcript", "", block))
    return found


def _needs_data(command: str) -> bool:
    return "../shared/data" in command


def _transcript(block: str, where: Path, capsys) -> str:
    parts = re.split(r"^\$ python -m magbench (.*)$", block, flags=re.M)
    lines = []
    for command in parts[1::2]:
        out, err = _run(command, where, capsys)
        lines += [f"$ python -m magbench {command}", out.rstrip("\n"), err.rstrip("\n")]
    return "\n".join(line for line in lines if line) + "\n"


def _params() -> list:
    """The examples as test parameters; a full fit (seconds) is marked slow."""
    out = []
    for page, kind, command, shown in _examples():
        fit = kind == "output"
        out.append(pytest.param(page, kind, command, shown, id=f"{page}:{command or shown}"[:70],
                                marks=[pytest.mark.slow] if fit else []))
    return out


@pytest.mark.parametrize("page, kind, command, shown", _params())
def test_the_page_shows_what_the_command_prints(page, kind, command, shown, tmp_path, capsys,
                                                monkeypatch):
    if _needs_data(command + shown) and not DATA:
        pytest.skip("set MAGBENCH_DATA to the shared recordings")
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(ROOT))
    got = _transcript(shown, tmp_path, capsys) if kind == "transcript" else \
        _run(command, tmp_path, capsys)[0]
    if UPDATE:
        path = ROOT / page
        path.write_text(path.read_text().replace(shown, got, 1))
        return
    assert _normal(got) == _normal(shown)


def test_the_flight_log_page_makes_the_log_the_test_makes():
    assert f'python -c "{FLIGHT}"' in (ROOT / "docs/flight_logs.md").read_text()


def _bash_commands() -> list[tuple[str, str]]:
    found = []
    for page in PAGES:
        for block in re.findall(r"```bash\n(.*?)```", (ROOT / page).read_text(), re.S):
            for line in block.splitlines():
                command = line.split("#")[0].strip()
                if command.startswith("python -m magbench") and \
                        ("my_log.csv" in command or "flight.csv" in command):
                    found.append((page, command))
    return found


@pytest.mark.slow
@pytest.mark.parametrize("page, command", _bash_commands())
def test_the_pages_own_file_commands_run(page, command, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    y = fibonacci_sphere(300) @ np.diag([50.0, 45.0, 52.0]) + [20.0, -10.0, 5.0]
    y += 0.2 * np.random.default_rng(0).standard_normal(y.shape)
    frame = pd.DataFrame(y, columns=["mx", "my", "mz"])
    frame.insert(0, "t", np.arange(len(y)) * 0.02)
    for name in ("my_log.csv", "flight.csv"):
        frame.to_csv(name, index=False)
    if "apply" in command:
        assert main(["calibrate", "file=my_log.csv", "out=cal/", "picture=false"]) == 0
    args = shlex.split(command)[3:]
    assert main(args) == 0, command
