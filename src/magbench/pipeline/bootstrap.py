"""Intervals that cover for ``calibrate``'s choice: the block bootstrap, :func:`bootstrap_check`.

Step 6 of :mod:`magbench.pipeline.calibration`, whose notes describe it: refits on circular
block resamples in time order, beside the model-based intervals of the gate step
(:mod:`magbench.pipeline.gate`).
"""

from __future__ import annotations

import functools

import numpy as np

from magbench.core.gauge import safe_gauge
from magbench.core.seeding import rng
from magbench.core.uncertainty import (
    Intervals,
    block_length,
    block_resample,
    correlation_length,
    student_t95,
)
from magbench.engine.isolation import map_supervised
from magbench.engine.plugins import plugin_modules
from magbench.engine.trial import run_method
from magbench.pipeline.fitting import fit_recording
from magbench.pipeline.holdout import estimate
from magbench.pipeline.result import CalibrationResult
from magbench.sources.recordings import Recording

__all__ = ["bootstrap_check"]


def _refit_gauge(rows: np.ndarray, rec: Recording, method: str, preprocess: str,
                 options: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """``b`` and ``A`` of ``method`` refitted on ``rec``'s ``rows``; None when the refit
    fails (one replicate fewer, not a failed command), whatever the way it fails."""
    out = run_method(method, lambda o: fit_recording(rec.rows(rows), method, preprocess, o),
                     options=options)
    if out.T is None or out.error:
        return None
    try:
        gauge = safe_gauge(out.T, out.h)
    except ValueError:
        return None
    return gauge.b, gauge.A


def bootstrap_check(result: CalibrationResult, B: int, *, preprocess: str = "centre",
                    options: dict | None = None, seed: int = 0) -> dict | None:
    """Block-bootstrap intervals of the choice, beside the model-based ones
    (:mod:`~magbench.pipeline.calibration`, step 6).

    ``calibrate_recording(..., bootstrap=B)`` runs it; ``bootstrap=0`` leaves it to the caller,
    which may then do other work first (``calibrate`` draws its picture in a second process
    meanwhile). The same arguments give the same answer either way.

    Returns
    -------
    dict or None
        ``block`` (samples per block) and ``correlation_samples``, ``replicates``, the
        bootstrap half-widths ``h_half_width`` and ``A_half_width`` (1.96 standard deviations
        of the refits), their ratios to the model-based ones, and the reported ``wider``
        half-widths with ``source_h`` and ``source_A`` (``block bootstrap`` or
        ``model-based``, the wider in most entries); None without a choice, without ``B``, or
        when fewer than ``max(10, B // 2)`` refits succeeded.
    """
    if not B or result.chosen is None or result.intervals is None:
        return None
    name = str(result.chosen["algorithm"])
    opts = dict((options or {}).get(name) or {})
    work = result.work
    T, h = estimate(result.chosen)
    residual = np.linalg.norm(np.linalg.solve(T, (work.y - h).T), axis=0) - 1.0
    block = block_length(residual)
    gen = rng(seed, "calibrate", "bootstrap", name)
    resamples = [np.sort(block_resample(work.K, block, gen)) for _ in range(B)]
    # Supervised as the candidates' fits are: a refit that ends its process is one replicate
    # fewer, not the end of calibrate.
    fits = map_supervised(functools.partial(_refit_gauge, rec=work, method=name,
                                            preprocess=preprocess, options=opts), resamples,
                          name=f"bootstrap refits of {name}", plugins=plugin_modules([name]))
    fits = [f for f in fits if f is not None]
    if len(fits) < max(10, B // 2):
        return None
    out = _bootstrap_summary(result.intervals, fits, block, correlation_length(residual),
                             work.K)
    return _with_halves(out, (result.verdict or {}).get("halves_offsets"))


def _with_halves(summary: dict, halves: list | None) -> dict:
    """The reported offset half-widths at least the distance between the offsets of the two
    halves of the recording: an offset that drifts slowly (temperature, a battery) moves less
    within a block than over the recording, which the block bootstrap cannot see."""
    if halves is None:
        return summary
    apart = np.abs(np.subtract(*np.asarray(halves, dtype=float)))
    wider = np.asarray(summary["wider_h"], dtype=float)
    out = {**summary, "halves_apart_h": apart.tolist(),
           "wider_h": np.maximum(wider, apart).tolist()}
    if np.mean(apart > wider) > 0.5:
        out["source_h"] = "time halves"
    return out


def _bootstrap_summary(iv: Intervals, fits: list, block: int, corr: float, K: int) -> dict:
    # Student's quantile with one degree of freedom per block less one: with a dozen blocks
    # the spread of the refits is itself uncertain, and 1.96 would cover too little.
    z = student_t95(int(np.ceil(K / block)) - 1)
    h_half = z * np.std([f[0] for f in fits], axis=0, ddof=1)
    A_half = z * np.std([f[1] for f in fits], axis=0, ddof=1)
    fixed = iv.model == "bias"                      # A is not estimated: no interval at all
    if fixed:
        A_half = np.zeros((3, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        rh = h_half / iv.h_half
        rA = (A_half / iv.A_half)[iv.A_half > 0]
    return {"kind": "circular block bootstrap over time", "block": int(block), "quantile": z,
            "correlation_samples": float(corr), "replicates": len(fits),
            "h_half_width": h_half.tolist(), "A_half_width": A_half.tolist(),
            "ratio_h": rh.tolist(),
            "ratio_A_median": float(np.median(rA)) if rA.size else None,
            "ratio_A_range": [float(rA.min()), float(rA.max())] if rA.size else None,
            "wider_h": np.maximum(h_half, iv.h_half).tolist(),
            "wider_A": np.maximum(A_half, iv.A_half).tolist(),
            "source_h": "block bootstrap" if np.mean(h_half > iv.h_half) > 0.5 else
            "model-based",
            "source_A": "not estimated" if fixed else "block bootstrap"
            if np.mean(A_half > iv.A_half) > 0.5 else "model-based"}
