"""Every navlib (and magcal) function magbench reimplements, run beside magbench's version.

Each pair of :data:`magbench.studies.peers.PEER_FITS` (the peer's adapter and its magbench
counterpart, called by :func:`magbench.calibrate`) is fitted on the same samples and the two
answers compared: the magnetometer-only pairs on the peer study's synthetic datasets
(nominal point, K = 300), the gyro-aided ones on simulated manoeuvres (distortion of eq. 68,
noise 0.005; MagFactor3 is also given the true attitude and field) and on the real recordings
that carry a gyro. Both answers are put in the symmetric gauge and scaled to unit mean
corrected norm on the fitting samples, so a rotation or a scale that no score sees is not
counted as a disagreement. Each dataset is split in two: the fits use one part and the
held-out part is corrected by both (time-ordered data: first and second half; the synthetic
lattice: even and odd samples). A peer whose modules are missing gives one row per pair
saying so, and the study runs without them.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from magbench.core.gauge import symmetric_T
from magbench.core.metrics import real_cost
from magbench.core.seeding import rng
from magbench.methods.api import calibrate
from magbench.sources.recordings import list_recordings, load_recording
from magbench.sources.synthetic import Point, make_dataset
from magbench.sources.trajectory import simulate
from magbench.studies.peers import PEER_FITS, fit_peer, missing_module, needs_gyro

__all__ = ["AGREEMENT_COLUMNS", "GYRO_RECORDINGS", "Sample", "agreement_row",
           "gyro_recordings", "peer_agreement", "simulated_manoeuvres",
           "summarize_peer_agreement", "synthetic_datasets"]

#: Real recordings with a gyro the gyro-aided pairs run on (name prefixes).
GYRO_RECORDINGS = ("broad", "tyrex_")
#: Samples per real recording at most (every s-th kept, as ``calibrate`` thins).
MAX_SAMPLES = 2000
AGREEMENT_COLUMNS = ["peer", "magbench", "data", "dataset", "status", "field_rel", "h_rel",
                     "T_rel", "Jr_peer", "Jr_magbench"]


class Sample:
    """One dataset split into a fitting and a held-out part, with the inputs a gyro-aided
    method takes on the fitting part (``inputs``: ``angular_rate``, ``time`` and, where
    known, ``attitude`` and ``reference_field``)."""

    def __init__(self, kind: str, name: str, y_fit: np.ndarray, y_test: np.ndarray,
                 inputs: dict | None = None) -> None:
        self.kind, self.name = kind, name
        self.y_fit, self.y_test = y_fit, y_test
        self.inputs = inputs or {}


def synthetic_datasets(n: int, seed: int = 0, K: int = 300) -> list[Sample]:
    """The peer study's nominal datasets, even samples fitted and odd ones held out."""
    out = []
    for trial in range(n):
        d = make_dataset(rng(seed, "peer-agreement", trial), Point(K=K))
        out.append(Sample("synthetic", f"synthetic {trial}", d.y[::2], d.y[1::2]))
    return out


def simulated_manoeuvres(n: int, seed: int = 0, mag_noise: float = 0.005) -> list[Sample]:
    """Manoeuvres of the gyro study's kind (25 Hz, 24 s), first half fitted."""
    out = []
    for trial in range(n):
        gen = rng(seed, "peer-agreement-gyro", trial)
        E = gen.uniform(-0.05, 0.05, (3, 3))
        T = gen.uniform(0.8, 1.2) * np.eye(3) + 0.5 * (E + E.T)
        traj = simulate(gen, T=T, h=gen.uniform(-0.05, 0.05, 3), mag_noise=mag_noise)
        half = traj.y.shape[0] // 2
        out.append(Sample("simulated", f"manoeuvre {trial}", traj.y[:half], traj.y[half:],
                          {"angular_rate": traj.angular_rate[:half], "time": traj.t[:half],
                           "attitude": traj.R[:half], "reference_field": traj.m0}))
    return out


def gyro_recordings(root: Path | str | None) -> list[Sample]:
    """The real recordings with a gyro (:data:`GYRO_RECORDINGS`), thinned to
    :data:`MAX_SAMPLES`, first half in time fitted; none without ``root``."""
    if root is None or not Path(root).is_dir():
        return []
    out = []
    for name in list_recordings(root):
        if not name.startswith(GYRO_RECORDINGS):
            continue
        rec = load_recording(root, name).thinned(MAX_SAMPLES)
        if not rec.has_gyro:
            continue
        fit, test = rec.halves()
        out.append(Sample("real", name, fit.y, test.y,
                          {"angular_rate": fit.gyro, "time": fit.t}))
    return out


def _unit(T: np.ndarray, h: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Symmetric ``T`` scaled so ``T^-1 (y - h)`` has unit mean norm: the gauge and the scale
    no score sees, removed before two answers are compared."""
    S = symmetric_T(np.asarray(T, dtype=float))
    m = np.linalg.solve(S, (y - h).T)
    return S * float(np.mean(np.linalg.norm(m, axis=0)))


def agreement_row(peer: str, sample: Sample) -> dict:
    """One pair on one dataset: relative differences of the held-out corrected field, of
    ``h`` (to the field's RMS magnitude in the samples) and of ``T`` (Frobenius), and each
    side's held-out J_r (eq. 81); ``status`` says why a number is missing."""
    ours = PEER_FITS[peer][2]
    base = {"peer": peer, "magbench": ours, "data": sample.kind, "dataset": sample.name}
    nan = dict.fromkeys(AGREEMENT_COLUMNS[5:], np.nan)
    gyro = {k: sample.inputs[k] for k in ("angular_rate", "time") if k in sample.inputs}
    extra = ({k: sample.inputs[k] for k in ("attitude", "reference_field")
              if k in sample.inputs} if ours == "magfactor3" else {})
    try:
        out = calibrate(sample.y_fit, ours, raw=True, **gyro, **extra)
        T_o, h_o = out.T, out.h
    except Exception as exc:                 # a failure is a row, as in every study
        return {**base, **nan, "status": f"magbench failed: {type(exc).__name__}"}
    try:
        with warnings.catch_warnings():      # a peer's own warnings are not ours
            warnings.simplefilter("ignore")
            T_p, h_p = fit_peer(peer, sample.y_fit, **sample.inputs)
    except Exception as exc:
        return {**base, **nan, "status": f"peer failed: {type(exc).__name__}: {exc}"[:120]}
    T_o, T_p = _unit(T_o, h_o, sample.y_fit), _unit(T_p, h_p, sample.y_fit)
    m_o = np.linalg.solve(T_o, (sample.y_test - h_o).T).T
    m_p = np.linalg.solve(T_p, (sample.y_test - h_p).T).T
    scale = float(np.sqrt(np.mean(np.sum((sample.y_fit - sample.y_fit.mean(0)) ** 2, 1))))
    rms = float(np.sqrt(np.mean(np.sum(m_o ** 2, axis=1))))
    return {**base, "status": "ok",
            "field_rel": float(np.sqrt(np.mean(np.sum((m_p - m_o) ** 2, axis=1)))) / rms,
            "h_rel": float(np.linalg.norm(h_p - h_o)) / scale,
            "T_rel": float(np.linalg.norm(T_p - T_o) / np.linalg.norm(T_o)),
            "Jr_peer": real_cost(sample.y_test, T_p, h_p),
            "Jr_magbench": real_cost(sample.y_test, T_o, h_o)}


def peer_agreement(peers: Sequence[str] | None = None, *, datasets: int = 20,
                   manoeuvres: int = 5, data_root: Path | str | None = None,
                   seed: int = 0) -> pd.DataFrame:
    """Every pair of ``peers`` (default: all of :data:`PEER_FITS`) on its datasets.

    Parameters
    ----------
    peers : sequence of str, optional
        Keys of :data:`PEER_FITS`.
    datasets, manoeuvres : int
        Synthetic datasets for the magnetometer-only pairs, simulated manoeuvres for the
        gyro-aided ones.
    data_root : path, optional
        Folder of the real recordings (the gyro-aided pairs also run on those with a gyro).
    seed : int
        Base seed of the synthetic data.

    Returns
    -------
    DataFrame
        :data:`AGREEMENT_COLUMNS`, one row per pair and dataset, or one row per pair
        (``status`` ``"not installed: <module>"``) when a module the peer needs is missing.
    """
    names = list(peers) if peers is not None else list(PEER_FITS)
    mag_only = synthetic_datasets(datasets, seed)
    gyro = (simulated_manoeuvres(manoeuvres, seed) + gyro_recordings(data_root)
            if any(needs_gyro(n) for n in names) else [])
    rows = []
    for peer in names:
        missing = missing_module(peer)
        if missing is not None:
            rows.append({"peer": peer, "magbench": PEER_FITS[peer][2], "data": "-",
                         "dataset": "-", "status": f"not installed: {missing}",
                         **dict.fromkeys(AGREEMENT_COLUMNS[5:], np.nan)})
            continue
        for sample in (gyro if needs_gyro(peer) else mag_only):
            if PEER_FITS[peer][2] == "magfactor3" and "attitude" not in sample.inputs:
                continue                      # MagFactor3 needs the attitude and the field
            rows.append(agreement_row(peer, sample))
    return pd.DataFrame(rows, columns=AGREEMENT_COLUMNS)


def summarize_peer_agreement(rows: pd.DataFrame) -> pd.DataFrame:
    """Per pair and kind of data: datasets, those compared, the first status that is not
    ``ok``, median and maximum of each relative difference, and median held-out J_r of
    each side.

    Returns
    -------
    DataFrame
        ``peer``, ``magbench``, ``data``, ``n``, ``n_ok``, ``status``, ``field_rel_median``,
        ``field_rel_max``, ``h_rel_median``, ``h_rel_max``, ``T_rel_median``, ``T_rel_max``,
        ``Jr_peer_median``, ``Jr_magbench_median``.
    """
    out = []
    for (peer, ours, data), g in rows.groupby(["peer", "magbench", "data"], sort=False):
        ok = g[g["status"] == "ok"]
        bad = g.loc[g["status"] != "ok", "status"]
        row = {"peer": peer, "magbench": ours, "data": data, "n": len(g), "n_ok": len(ok),
               "status": "ok" if bad.empty else str(bad.iloc[0])}
        for part in ("field_rel", "h_rel", "T_rel"):
            row[f"{part}_median"] = ok[part].median()
            row[f"{part}_max"] = ok[part].max()
        row["Jr_peer_median"] = ok["Jr_peer"].median()
        row["Jr_magbench_median"] = ok["Jr_magbench"].median()
        out.append(row)
    return pd.DataFrame(out)
