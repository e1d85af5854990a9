"""The published numbers and claims (``reference/paper_values.yaml``), read once."""

from __future__ import annotations

from functools import cache
from importlib import resources

import yaml

__all__ = ["paper_values"]


@cache
def paper_values() -> dict:
    """The published numbers (copied from the source documents into the package)."""
    text = resources.files("magbench").joinpath("reference/paper_values.yaml").read_text()
    return _numbers(yaml.safe_load(text))


def _numbers(node: object) -> object:
    # PyYAML follows YAML 1.1, which reads exponent floats without a sign ("3.31e3") as strings.
    if isinstance(node, dict):
        return {k: _numbers(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_numbers(v) for v in node]
    if isinstance(node, str):
        try:
            return float(node)
        except ValueError:
            return node
    return node
