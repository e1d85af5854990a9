"""The peers' accuracy on three geometries: the rows, the pairing, the lattice effect."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from magbench.studies.peer_accuracy import peer_accuracy, summarize_peer_accuracy
from magbench.studies.speed import PEERS


@pytest.fixture(scope="module")
def rows():
    return peer_accuracy(PEERS, datasets=4, K=120)


def test_every_tool_on_every_dataset_of_every_geometry(rows):
    tools = rows["tool"].unique()
    assert {"magbench.als", "magbench.ellipsoid", "magbench.fang"} <= set(tools)
    assert len(rows) == 3 * 4 * len(tools)
    assert rows["ok"].all()
    np.testing.assert_allclose(rows["J"], rows["J_h"] + rows["J_T"], rtol=1e-12)


def test_the_lattice_is_balanced_and_random_directions_are_not(rows):
    offset = rows.groupby("geometry")["mean_offset"].mean()
    assert offset["lattice"] < 1e-2 < offset["random"] < 0.2 < offset["cap 120 deg"]


def test_summary_intervals_bracket_the_means(rows):
    summary = summarize_peer_accuracy(rows)
    assert len(summary) == 3 * rows["tool"].nunique() and (summary["n"] == 4).all()
    for part in ("J_h", "J_T", "J"):
        assert (summary[f"{part}_lo"] <= summary[part]).all()
        assert (summary[part] <= summary[f"{part}_hi"]).all()
    # The efficient fits sit near the Cramer-Rao floor on every geometry.
    ours = summary[summary["tool"] == "magbench.als"]
    assert (ours["rms_h"] < 3 * ours["crb_rms_h"]).all()


@pytest.mark.skipif(importlib.util.find_spec("magcal") is None, reason="peer magcal not installed")
def test_centring_on_the_sample_mean_errs_by_the_directions_offset(rows):
    # magcal's fit centres on the sample mean: its hard-iron error is T times the mean
    # direction, about |mean(m)| (T ~ I), where the balanced lattice makes it vanish.
    magcal = rows[rows["tool"] == "magcal.ellipsoid_fit"].set_index(["geometry", "trial"])
    off = magcal.loc["cap 120 deg"]
    np.testing.assert_allclose(off["J_h"], off["mean_offset"], rtol=0.3)
    assert magcal.loc["lattice", "J_h"].mean() < 0.1 * magcal.loc["random", "J_h"].mean()
