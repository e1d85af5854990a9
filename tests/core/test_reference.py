"""The published numbers and claims the report sets beside this run."""

from pathlib import Path

import pytest
import yaml

from magbench.core.reference import _numbers, paper_values

#: The transcription every helper reads; the package carries a copy of it.
SHARED = Path("/work/shared/reference/paper_values.yaml")


def test_exponent_floats_are_numbers_and_claims_are_keyed_by_id():
    values = paper_values()
    assert values["review"]["table2"]["Crassidis"]["accuracy"] == 3310.0
    claims = values["review"]["claims"]
    assert all(isinstance(c, dict) for c in claims.values())
    assert claims["fig4_K"]["time_linear"] == "execution time grows linearly with K"
    assert set(values["wu_shi"]["claims"]) == {"converge_in_five", "ml_costs_ten_nm",
                                               "ml_better", "nm_diverges"}


def _leaves(node: object, path: tuple = ()) -> set[tuple]:
    """(path, value) of every number and text; a claim's id or list position is left out of
    its path, so that ids added to a list of claims compare equal."""
    if isinstance(node, dict | list):
        items = node.items() if isinstance(node, dict) else enumerate(node)
        claims = "claims" in path
        return set().union(*(_leaves(v, path if claims else (*path, k)) for k, v in items))
    return {(path, str(node))}


def test_the_package_copy_is_the_shared_transcription():
    if not SHARED.exists():
        pytest.skip("no shared reference folder on this machine")
    shared = _leaves(_numbers(yaml.safe_load(SHARED.read_text())))
    package = _leaves(paper_values())
    # Every number and claim transcribed there is here; here may add claims, nothing else.
    assert shared <= package
    assert all("claims" in path for path, _ in package - shared)
