"""The README's Run commands can be run in order on a fresh clone without touching results/."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: Commands that write into results/ on purpose: recomputing or redrawing the committed run.
REGENERATE = {"make reproduce", "python -m magbench report", "python -m magbench bench"}


def run_commands() -> list[str]:
    """The shell commands of the README's "## Run" code block, comments removed."""
    text = (REPO / "README.md").read_text()
    section = text.split("\n## Run\n", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    return [line.split("#", 1)[0].strip() for line in block.splitlines()
            if line.split("#", 1)[0].strip()]


def test_the_run_block_is_found():
    commands = run_commands()
    assert "make reproduce" in commands and len(commands) >= 5


def test_every_example_sweep_writes_outside_the_committed_results():
    for command in run_commands():
        words = shlex.split(command)
        if command in REGENERATE or words[:3] != ["python", "-m", "magbench"]:
            continue
        args = [a for a in words[3:] if a != "run"]
        if any("=" not in a for a in args):
            continue  # --help, methods, calibrate, apply: they never write into results/
        targets = [a.split("=", 1)[1] for a in args if a.startswith("results_dir=")]
        assert targets and not Path(targets[0]).resolve().is_relative_to(REPO / "results"), \
            f"README example would write into the committed results/: {command}"


def test_the_key_table_names_every_sweep():
    row = next(line for line in (REPO / "README.md").read_text().splitlines()
               if line.startswith("| `sweep` |"))
    listed = set(re.findall(r"`(\w+)`", row.split("|")[2]))
    assert listed == {p.stem for p in (REPO / "conf" / "sweep").glob("*.yaml")}
