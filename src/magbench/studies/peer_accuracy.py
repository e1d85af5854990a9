"""The peers' accuracy against magbench's on three direction geometries, J_h and J_T apart.

The review's datasets (Algorithm 8) take the field directions from a Fibonacci lattice, whose
directions sum almost exactly to zero (a balanced design). A fit that centres the samples on
their mean, as magcal's ellipsoid fit does before its algebraic step, then starts from the
true centre: on the lattice it looks better than any estimator can be on general data, and on
random directions or a partial cap the mean is off the centre and so is the fit. This study
runs every installed peer and its magbench counterpart (plus the consistent ALS fit and
MAG.I.C.AL as references) on the same datasets under three geometries: the lattice, uniform
random directions, and the lattice over a 120-degree polar cap (the coverage sweep's
geometry). The distortion and the noise of a trial are the same in all three (one generator
per trial), so the geometries are compared on paired datasets. Each dataset also carries its
Cramer-Rao bound on ``E[J_h^2]`` and ``E[J_T^2]``, the floor of an unbiased estimator.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from magbench.core.crb import crb_mse
from magbench.core.intervals import bootstrap_mean
from magbench.core.metrics import accuracy_cost, sample_mean
from magbench.core.seeding import rng
from magbench.methods.api import calibrate
from magbench.sources.synthetic import Point, make_dataset

__all__ = ["GEOMETRIES", "REFERENCES", "peer_accuracy", "summarize_peer_accuracy"]

#: Geometry name -> the point it uses (directions: ``"random"`` or the point's lattice).
GEOMETRIES = {"lattice": Point(), "random": Point(), "cap 120 deg": Point(cap_deg=120.0)}
#: magbench methods run beside the peers' counterparts.
REFERENCES = ("als", "magical")


def _directions(geometry: str, point: Point, seed: int, trial: int) -> np.ndarray:
    if geometry != "random":
        return point.directions
    v = rng(seed, "peer-directions", trial).standard_normal((point.K, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


#: A peer: its package, its fit (samples -> (T, h)) and the magbench method it is paired with.
Peers = Mapping[str, tuple[str, Callable, str]]


def _tools(peers: Peers) -> list[tuple[str, Callable]]:
    """(name, fit returning (T, h)) of every installed peer and the magbench methods."""
    tools = [(peer, fn) for peer, (package, fn, _) in peers.items()
             if importlib.util.find_spec(package) is not None]
    ours = list(dict.fromkeys([c for _, (_, _, c) in peers.items()] + list(REFERENCES)))
    for name in ours:
        tools.append((f"magbench.{name}",
                      lambda y, n=name: (lambda c: (c.T, c.h))(calibrate(y, n, raw=True))))
    return tools


def peer_accuracy(peers: Peers, datasets: int = 200, K: int = 300, seed: int = 0,
                  geometries: Sequence[str] = tuple(GEOMETRIES)) -> pd.DataFrame:
    """One row per geometry, dataset and tool: J_h, J_T, J of eq. (74) and the dataset's bound.

    Parameters
    ----------
    peers : mapping
        Peer name -> (package, fit, magbench counterpart), as
        :data:`magbench.studies.speed.PEERS`; a peer whose package is not installed is left
        out, its counterpart still runs.
    datasets, K, seed : int
        Datasets per geometry, samples per dataset, base seed.
    geometries : sequence of str
        Keys of :data:`GEOMETRIES`.

    Returns
    -------
    DataFrame
        Columns ``geometry``, ``trial``, ``tool``, ``ok``, ``J_h``, ``J_T``, ``J`` (NaN where
        the tool failed), ``crb_h``, ``crb_T`` (the Cramer-Rao bounds on ``E[J_h^2]`` and
        ``E[J_T^2]``) and ``mean_offset`` (``|mean of the true directions|``: 0 for a balanced
        design).
    """
    rows = []
    tools = _tools(peers)
    for geometry in geometries:
        point = Point(**{**GEOMETRIES[geometry].__dict__, "K": K})
        for trial in range(datasets):
            directions = _directions(geometry, point, seed, trial)
            data = make_dataset(rng(seed, "peers", trial), point, directions)
            bound = crb_mse(data.T, data.h, data.m, point.sigma)
            base = {"geometry": geometry, "trial": trial, "crb_h": bound.h_part,
                    "crb_T": bound.T_part,
                    "mean_offset": float(np.linalg.norm(sample_mean(data.m)))}
            for name, fit in tools:
                try:
                    T, h = fit(data.y)
                    J, J_h, J_T = accuracy_cost(np.asarray(T), np.asarray(h), data.T, data.h)
                    ok = bool(np.isfinite(J))
                except Exception:
                    J = J_h = J_T = np.nan
                    ok = False
                rows.append({**base, "tool": name, "ok": ok, "J_h": J_h, "J_T": J_T, "J": J})
    return pd.DataFrame(rows)


def summarize_peer_accuracy(rows: pd.DataFrame) -> pd.DataFrame:
    """Per geometry and tool: mean J_h, J_T and J with 95 % bootstrap intervals, and the
    root of the mean bound of each part beside the root mean square error.

    Returns
    -------
    DataFrame
        ``geometry``, ``tool``, ``n``, ``failures``, ``J_h``, ``J_h_lo``, ``J_h_hi``, ``J_T``,
        ``J_T_lo``, ``J_T_hi``, ``J``, ``J_lo``, ``J_hi``, ``rms_h``, ``crb_rms_h``,
        ``rms_T``, ``crb_rms_T`` (``sqrt(mean J_h^2)`` against ``sqrt(mean bound)``: an
        unbiased estimator has ``rms >= crb_rms``) and ``mean_offset`` (mean over datasets).
    """
    out = []
    for (geometry, tool), g in rows.groupby(["geometry", "tool"], sort=False):
        ok = g[g["ok"].astype(bool)]
        row = {"geometry": geometry, "tool": tool, "n": len(g), "failures": len(g) - len(ok)}
        for part in ("J_h", "J_T", "J"):
            low, high = bootstrap_mean(ok[part], "peers", geometry, tool, part)
            row.update({part: ok[part].mean(), f"{part}_lo": low, f"{part}_hi": high})
        for part, bound in (("h", "crb_h"), ("T", "crb_T")):
            row[f"rms_{part}"] = float(np.sqrt(np.mean(ok[f"J_{part}"] ** 2)))
            row[f"crb_rms_{part}"] = float(np.sqrt(ok[bound].mean()))
        row["mean_offset"] = float(g["mean_offset"].mean())
        out.append(row)
    return pd.DataFrame(out)
