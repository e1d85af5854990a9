"""The bench section's peer-accuracy table, from ``bench/peer_accuracy_summary.csv``.

Per direction geometry and tool: mean J_h and J_T of eq. (74) apart, with their 95 %
bootstrap intervals, and the root mean square of each against the root of its mean
Cramer-Rao bound. The prose explains magcal's lattice effect from the same numbers: its fit
is centred on the sample mean, exact only for balanced directions
(:mod:`magbench.studies.peer_accuracy`).
"""

from __future__ import annotations

import pandas as pd

from magbench.methods.registry import method_label
from magbench.report.format import compact_number, format_number, render

__all__ = ["AGREE", "CENTRED", "LATTICE", "REASONS", "peer_accuracy_lines",
           "peer_agreement_lines"]

#: The peer whose fit is centred on the sample mean, and the magbench fit it is set against.
CENTRED = ("magcal.ellipsoid_fit", "magbench.ellipsoid")
#: The geometry of the review's datasets (a balanced Fibonacci lattice).
LATTICE = "lattice"


def _tool(name: str) -> str:
    ours = name.removeprefix("magbench.")
    return name if ours == name else f"magbench {method_label(ours)}"


def _interval(row: pd.Series, part: str) -> str:
    return (f"{format_number(row[part])} [{format_number(row[f'{part}_lo'])}, "
            f"{format_number(row[f'{part}_hi'])}]")


def _times(ratio: float) -> str:
    """A ratio as a factor: ``0.55x``, ``58x``, ``210x``."""
    return f"{ratio:.0f}x" if ratio >= 10 else f"{compact_number(ratio, 2)}x"


def peer_accuracy_lines(summary: pd.DataFrame) -> list[str]:
    """Markdown lines: the table per geometry and tool, then the lattice explanation."""
    lines = ["", render("bench.peer_accuracy", n=int(summary["n"].max())), "",
             "| geometry | tool | failures | mean J_h [95 %] | mean J_T [95 %] | "
             "rms J_h / CRB | rms J_T / CRB |", "|---|---|---:|---:|---:|---:|---:|"]
    for _, r in summary.iterrows():
        lines.append(f"| {r['geometry']} | {_tool(r['tool'])} | {int(r['failures'])} | "
                     f"{_interval(r, 'J_h')} | {_interval(r, 'J_T')} | "
                     f"{format_number(r['rms_h'])} / {format_number(r['crb_rms_h'])} | "
                     f"{format_number(r['rms_T'])} / {format_number(r['crb_rms_T'])} |")
    explanation = lattice_explanation(summary)
    return lines + (["", explanation] if explanation else [])


def lattice_explanation(summary: pd.DataFrame) -> str:
    """Why the sample-mean-centred peer looks best on the lattice, from its numbers ('' when
    the peer, its magbench counterpart or the lattice rows are absent)."""
    peer, ours = CENTRED
    table = summary.set_index(["geometry", "tool"])
    geometries = list(dict.fromkeys(summary["geometry"]))
    if (LATTICE, peer) not in table.index or (LATTICE, ours) not in table.index:
        return ""
    lat = table.loc[(LATTICE, peer)]
    crb = compact_number(lat["crb_rms_h"])
    where = (f"even below the Cramer-Rao floor ({crb}): the bound is for an estimator that "
             "does not know the directions are balanced, and this one uses the balance"
             if lat["rms_h"] < lat["crb_rms_h"] else f"above the Cramer-Rao floor ({crb})")
    others = [g for g in geometries if g != LATTICE and (g, peer) in table.index
              and (g, ours) in table.index]
    worse = "; ".join(
        f"on {'random directions' if g == 'random' else g}: mean J_h "
        f"{compact_number(table.loc[(g, peer), 'J_h'])}, "
        f"{_times(table.loc[(g, peer), 'J_h'] / table.loc[(g, ours), 'J_h'])} "
        f"magbench's (|mean of the directions| "
        f"{compact_number(table.loc[(g, peer), 'mean_offset'], 2)})"
        for g in others)
    return render("bench.lattice", peer=peer, ours=_tool(ours),
                  offset=compact_number(lat["mean_offset"], 2),
                  rms=compact_number(lat["rms_h"]), where=where,
                  ratio=_times(lat["J_h"] / table.loc[(LATTICE, ours), "J_h"]),
                  worse=worse or "no other geometry in this run")


#: Largest held-out relative field difference at which a pair is said to agree.
AGREE = 1e-3

#: Why a pair differs by more than :data:`AGREE`, as measured when the study was written
#: (docs/decisions.md, "navlib beside magbench"); shown beside the pair's own numbers.
REASONS = {
    "navlib.cal_mag_ellipsoid_fit": "same centre to rounding; navlib's soft-iron matrix (the "
    "one its own corrected field applies) is a different conversion of the fitted quadric, "
    "so its held-out J_r is larger",
    "navlib.cal_mag_twostep_hi": "navlib's default noise std (1e-3 against 0.005) and its "
    "stopping rule; navlib also raises UnboundLocalError on some datasets",
    "navlib.cal_mag_sar_ls": "navlib squares the skew-symmetric rate matrix element by "
    "element where the normal equations need the matrix product, and differentiates one-sided;"
    " it misses the hard iron even on noise-free data",
    "navlib.cal_mag_sar_kf": "navlib returns the mean of the last 20 % of its estimates with "
    "fixed gains; on noise-free data its estimate is far from the truth (cause not traced "
    "further)",
    "navlib.cal_mag_sar_aid": "navlib integrates the observer by forward Euler and averages "
    "the last 20 %; on noise-free data its estimate is far from the truth",
    "navlib.cal_mag_magyc_ls": "navlib's one-sided derivative (first order, error growing "
    "with dt |w|) against magbench's midpoint difference, and an iterative solve from zero",
    "navlib.cal_mag_magyc_nls": "navlib's one-sided derivative against magbench's midpoint "
    "difference, and navlib's start from C = I, b = d = 0",
    "magcal.ellipsoid_fit": "magcal centres the samples on their mean before its algebraic "
    "step (the lattice effect above)",
    "magcal.sphere_fit": "a different centre by about 0.2 % of the field, same held-out "
    "J_r (cause not traced)",
}


def _verdict(row: pd.Series) -> str:
    """One line: agreement within the measured bound, or the difference and its reason."""
    if row["status"] != "ok" and not row["n_ok"]:
        return str(row["status"])
    failed = "" if row["status"] == "ok" else f" ({int(row['n'] - row['n_ok'])} " \
        f"failed: {row['status']})"
    if row["field_rel_max"] <= AGREE:
        return f"agree within {compact_number(row['field_rel_max'], 2)}{failed}"
    reason = REASONS.get(row["peer"], "cause not traced")
    return (f"differ (field up to {compact_number(row['field_rel_max'], 2)}): "
            f"{reason}{failed}")


def peer_agreement_lines(summary: pd.DataFrame) -> list[str]:
    """Markdown lines: each navlib/magcal function beside magbench's reimplementation, from
    ``bench/peer_agreement_summary.csv`` (:mod:`magbench.studies.peer_agreement`)."""
    lines = ["", "Each peer function magbench reimplements, run beside magbench's version "
             "on the same samples (`peer_agreement.csv`): relative difference of the "
             "held-out corrected field, of h (to the field's magnitude) and of T, both in "
             "the symmetric gauge at unit mean norm, and each side's held-out J_r (medians; "
             "field: median / max).", "",
             "| peer | magbench | data | compared | field | h | T | J_r peer | J_r magbench | "
             "verdict |", "|---|---|---|---:|---:|---:|---:|---:|---:|---|"]
    for _, r in summary.iterrows():
        lines.append(
            f"| {r['peer']} | {_tool('magbench.' + r['magbench'])} | {r['data']} | "
            f"{int(r['n_ok'])} of {int(r['n'])} | {format_number(r['field_rel_median'])} / "
            f"{format_number(r['field_rel_max'])} | {format_number(r['h_rel_median'])} | "
            f"{format_number(r['T_rel_median'])} | {format_number(r['Jr_peer_median'])} | "
            f"{format_number(r['Jr_magbench_median'])} | {_verdict(r)} |")
    return lines
