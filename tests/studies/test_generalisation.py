"""The generalisation study: protocols, scores, the case and protocol tables, one unit."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from magbench.core.geometry import fibonacci_sphere, sphere_fit, unit_rows
from magbench.sources.recordings import Recording
from magbench.studies.generalisation import (
    AUTO,
    BAND_DEG,
    MIN_PART,
    PROTOCOLS,
    SPIKE_SHARE,
    GeneralisationStudy,
    case_table,
    protocol_table,
    scores,
    split,
    tolerance,
    tolerance_deg,
)

T_TRUE = np.array([[52.0, 2.0, -0.8], [0.0, 47.0, 1.5], [0.0, 0.0, 61.0]])
H_TRUE = np.array([90.0, -35.0, 12.0])


def rotating(K: int = 1500, seed: int = 0, noise: float = 0.3) -> Recording:
    """A sensor turned smoothly through every direction (a spiral), in time order."""
    s = np.linspace(0.0, 1.0, K)
    theta, phi = np.arccos(1 - 2 * s), 2 * np.pi * 12 * s        # pole to pole, 12 turns
    m = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                         np.cos(theta)])
    y = m @ T_TRUE.T + H_TRUE + noise * np.random.default_rng(seed + 1).standard_normal((K, 3))
    return Recording("spiral", y, t=np.arange(K) * 0.02, n_rows=K)


def test_blocks_half_and_first15_partition_the_recording_in_time():
    rec = rotating()
    for protocol, share in (("blocks", 0.5), ("half", 0.5), ("first15", 0.15)):
        fit, test = split(rec, protocol)
        assert fit.K + test.K == rec.K
        assert fit.K == pytest.approx(share * rec.K, abs=rec.K / 20)
        assert set(map(tuple, fit.y)).isdisjoint(map(tuple, test.y))
    fit, test = split(rec, "half")
    assert fit.t.max() < test.t.min()                      # fitted before scored


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_band_fits_only_directions_near_one_plane(axis):
    rec = rotating()
    fit, test = split(rec, f"band_{'xyz'[axis]}")
    centre = sphere_fit(rec.y)[0]
    elevation = np.degrees(np.arcsin(np.abs(unit_rows(fit.y - centre)[:, axis])))
    assert elevation.max() <= BAND_DEG
    rest = np.degrees(np.arcsin(np.abs(unit_rows(test.y - centre)[:, axis])))
    assert rest.min() > BAND_DEG and fit.K + test.K == rec.K


def test_spikes_move_exactly_their_share_of_the_fitted_samples():
    rec = rotating()
    clean, _ = split(rec, "blocks")
    spiky, test = split(rec, "spikes", seed=3)
    moved = np.any(clean.y != spiky.y, axis=1)
    assert moved.sum() == round(SPIKE_SHARE * clean.K)
    assert np.array_equal(split(rec, "spikes", seed=3)[0].y, spiky.y)   # seeded
    assert test.K == rec.K - clean.K


def test_still_first_prepends_a_still_half_before_the_fitted_blocks():
    rec = rotating()
    blocks, _ = split(rec, "blocks")
    fit, _ = split(rec, "still_first")
    n = blocks.K
    assert fit.K == 2 * n
    assert np.array_equal(fit.y[n:], blocks.y)
    assert np.all(np.diff(fit.t) > 0)
    # still: spread about the first sample at the recording's own noise, far below the field
    assert np.linalg.norm(fit.y[:n] - blocks.y[0], axis=1).max() < 3.0


def test_a_protocol_that_leaves_too_few_samples_is_skipped_with_the_reason():
    rec = rotating(K=100)
    out = split(rec, "first15")
    assert isinstance(out, str) and f"({MIN_PART} needed each)" in out


def test_scores_know_the_answer():
    u = fibonacci_sphere(400)
    rec = Recording("r", 2.0 * u + [5.0, 0.0, 0.0], n_rows=400)
    spread, direction, heading = scores(rec, np.eye(3) / 2.0, np.array([5.0, 0.0, 0.0]))
    assert spread == pytest.approx(0.0, abs=1e-9) and np.isnan(direction) and np.isnan(heading)
    norm = np.linalg.norm(rec.y, axis=1)
    assert scores(rec)[0] == pytest.approx(100 * norm.std() / norm.mean())
    # raw data as a share of the field (radius 2), not of their mean norm (about 5)
    assert scores(rec, field=2.0)[0] == pytest.approx(100 * norm.std() / 2.0)
    assert scores(rec, field=2.0)[0] > 2 * scores(rec)[0]
    # an attitude that turns each sample's field onto +x: no direction spread in the world
    q = np.array([_quat_to_x(v) for v in u])
    att = Recording("a", rec.y, n_rows=400,
                    extra={"qw": q[:, 0], "qx": q[:, 1], "qy": q[:, 2], "qz": q[:, 3]})
    assert scores(att, np.eye(3) / 2.0, np.array([5.0, 0.0, 0.0]))[1] == \
        pytest.approx(0.0, abs=1e-6)
    # the heading against the world field: none on +x, 30 deg against a field 30 deg away
    # in azimuth (and dipping: the inclination is not the heading); NaN without a reference
    A, b = np.eye(3) / 2.0, np.array([5.0, 0.0, 0.0])
    assert np.isnan(scores(att, A, b)[2])
    assert scores(att, A, b, reference=np.array([1.0, 0.0, 0.0]))[2] == \
        pytest.approx(0.0, abs=1e-6)
    a = np.radians(30.0)
    assert scores(att, A, b, reference=np.array([np.cos(a), np.sin(a), -1.0]))[2] == \
        pytest.approx(30.0, abs=1e-6)


def _quat_to_x(v: np.ndarray) -> np.ndarray:
    """The shortest rotation (scalar first) taking unit ``v`` to +x."""
    x = np.array([1.0, 0.0, 0.0])
    axis = np.cross(v, x)
    s, c = np.linalg.norm(axis), float(v @ x)
    if s < 1e-12:
        return np.array([1.0, 0, 0, 0]) if c > 0 else np.array([0.0, 0, 0, 1])
    angle = np.arctan2(s, c)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis / s])


def _rows(dataset, protocol, auto, fixed, raw=10.0, peers=(), raw_mean=None):
    """A case's rows: ``auto`` (spread or None for nothing written), fixed name -> spread."""
    base = {"dataset": dataset, "protocol": protocol, "raw_spread_pct": raw,
            "raw_mean_spread_pct": raw if raw_mean is None else raw_mean,
            "raw_direction_deg": np.nan, "direction_deg": np.nan, "raw_heading_deg": np.nan,
            "heading_deg": np.nan, "degenerate": False,
            "method": ""}
    rows = [{**base, "algorithm": AUTO, "kind": "auto", "status": "PASS" if auto else "FAIL",
             "written": auto is not None, "spread_pct": auto if auto else np.nan}]
    for kind, table in (("fixed", fixed), ("peer", dict(peers))):
        rows += [{**base, "algorithm": n, "kind": kind, "status": "ok", "written": True,
                  "spread_pct": v} for n, v in table.items()]
    return rows


def test_case_and_protocol_tables_count_losses_harm_and_needless_fails():
    trials = pd.DataFrame(
        _rows("a", "half", 1.0, {"sphere": 1.0, "fang": 0.9})              # tie
        + _rows("b", "half", 2.0, {"sphere": 1.0, "fang": 3.0})            # loss
        + _rows("c", "half", 12.0, {"sphere": 11.0, "fang": 11.5})         # harmful + loss
        + _rows("d", "half", None, {"sphere": 4.0, "fang": 5.0})           # needless FAIL
        + _rows("e", "blocks", None, {"sphere": 11.0, "fang": 12.0})       # a fair FAIL
    )
    cases = case_table(trials).set_index("dataset")
    assert list(cases["loss"]) == [False, True, True, True, False]
    assert list(cases["harmful"]) == [False, False, True, False, False]
    assert list(cases["needless_fail"]) == [False, False, False, True, False]
    assert cases.loc["d", "auto_pct"] == 10.0                     # the raw data is what is left
    assert cases.loc["b", "best_fixed"] == "sphere"
    assert cases.loc["b", "regret"] == pytest.approx(1.0)
    table = protocol_table(cases.reset_index()).set_index("protocol")
    assert table.loc["half", "losses"] == 3 and table.loc["all", "cases"] == 5
    # against sphere: a tie, a loss (2 vs 1), a loss (12 vs 11 > 0.55), a loss (10 vs 4)
    assert table.loc["half", "wtl:sphere"] == "0/1/3"
    assert table.loc["blocks", "wtl:fang"] == "1/0/0"             # 10 raw vs 12: a win


def test_the_fits_the_choice_passed_over_are_carried_to_the_cases_and_counted():
    trials = pd.DataFrame(_rows("a", "band_x", 1.0, {"sphere": 1.0})
                          + _rows("b", "band_x", 2.0, {"sphere": 1.0})
                          + _rows("c", "half", 1.0, {"sphere": 1.0}))
    trials["passed_over"] = ""
    trials.loc[(trials["dataset"] == "a") & (trials["kind"] == "auto"),
               "passed_over"] = "twostep;wu_shi_nm"
    cases = case_table(trials).set_index("dataset")
    assert list(cases["passed_over"]) == ["twostep;wu_shi_nm", "", ""]
    table = protocol_table(cases.reset_index()).set_index("protocol")
    assert table.loc["band_x", "passed_over"] == 1 and table.loc["half", "passed_over"] == 0
    assert table.loc["all", "passed_over"] == 1
    # rows written before the column existed: none passed over
    old = case_table(trials.drop(columns="passed_over"))
    assert (old["passed_over"] == "").all()


def test_harm_is_judged_against_the_raw_field_share_and_beside_by_mean_norm():
    # a large offset: raw spreads 40 % of the field but 4 % of its mean norm
    cases = case_table(pd.DataFrame(_rows("p", "half", 6.0, {"sphere": 6.0}, raw=40.0,
                                          raw_mean=4.0)))
    assert not cases.loc[0, "harmful"] and cases.loc[0, "harmful_mean_norm"]
    # nothing written: the user keeps raw data at 40 % of the field, a needless FAIL
    cases = case_table(pd.DataFrame(_rows("p", "half", None, {"sphere": 6.0}, raw=40.0,
                                          raw_mean=4.0)))
    assert cases.loc[0, "auto_pct"] == 40.0 and cases.loc[0, "needless_fail"]


def test_direction_losses_use_their_own_tolerance():
    def case(auto_deg, written=True):
        rows = _rows("p", "half", 6.0 if written else None, {"sphere": 6.0, "fang": 6.0})
        for r, d in zip(rows, (auto_deg, 10.0, 20.0), strict=True):
            r["raw_direction_deg"], r["direction_deg"] = 60.0, d
            r["raw_heading_deg"], r["heading_deg"] = 60.0, d
        return case_table(pd.DataFrame(rows)).loc[0]

    assert not case(11.0)["loss_direction"]                # within 10 % of the best, 10 deg
    assert case(11.5)["loss_direction"]
    assert case(np.nan, written=False)["loss_direction"]    # raw 60 deg is what is left
    table = protocol_table(pd.DataFrame([case(11.5), case(5.0)]))
    assert table.loc[0, "losses_direction"] == 1 and table.loc[0, "direction_cases"] == 2
    assert case(11.5)["loss_heading"] and not case(11.0)["loss_heading"]
    # with an attitude the compass score is the heading's, without one the magnitude's
    assert case(11.5)["loss_compass"] and not case(11.0)["loss_compass"]
    assert table.loc[0, "losses_compass"] == 1
    plain = case_table(pd.DataFrame(_rows("q", "half", 2.0, {"sphere": 1.0}))).loc[0]
    assert not plain["has_attitude"] and plain["loss"] and plain["loss_compass"]


def test_compass_harm_and_needless_fails_and_the_peers_comparison():
    def case(auto, auto_deg, fixed_deg, peers=()):
        rows = _rows("p", "half", auto, {"sphere": 6.0, "fang": 6.0}, raw=40.0, peers=peers)
        for r, d in zip(rows, (auto_deg, *fixed_deg, *[np.nan] * len(peers)), strict=True):
            r["raw_direction_deg"], r["direction_deg"] = 20.0, d
            r["raw_heading_deg"], r["heading_deg"] = 20.0, d
        return case_table(pd.DataFrame(rows)).loc[0]

    # nothing written; by magnitude a fit would have helped (40 % raw), but by heading
    # every fixed fit is worse than the raw data's 20 deg: no needless FAIL by the compass
    worse = case(None, np.nan, (30.0, 25.0))
    assert worse["needless_fail"] and not worse["needless_fail_compass"]
    better = case(None, np.nan, (12.0, 25.0))
    assert better["needless_fail_compass"]
    # written and turning the field further astray than raw: harmful by the compass
    astray = case(6.0, 22.5, (12.0, 25.0))
    assert not astray["harmful"] and astray["harmful_compass"]
    # the peers: 6.0 against a peer's 5.8 ties (tolerance 0.29), against 5.0 loses
    assert not case(6.0, 12.0, (12.0, 12.0), {"navlib.x": 5.8})["loss_peers"]
    lost = case(6.0, 12.0, (12.0, 12.0), {"navlib.x": 5.0, "magcal.y": 7.0})
    assert lost["loss_peers"] and not case(6.0, 12.0, (12.0, 12.0))["loss_peers"]
    table = protocol_table(pd.DataFrame([worse, better, astray, lost]))
    assert table.loc[0, ["needless_fail", "needless_fail_compass", "harmful_compass",
                         "losses_peers"]].tolist() == [2, 1, 1, 1]


def test_the_compass_scores_the_heading_not_the_spread_about_its_own_mean():
    # raw data that barely turn: 20 deg of spread about their own mean, but 95 deg from the
    # world field; a fit spreads 30 deg and points within 25 deg of the field
    rows = _rows("p", "half", None, {"sphere": 6.0}, raw=40.0)
    for r, (d, h) in zip(rows, ((np.nan, np.nan), (30.0, 25.0)), strict=True):
        r["raw_direction_deg"], r["direction_deg"] = 20.0, d
        r["raw_heading_deg"], r["heading_deg"] = 95.0, h
    row = case_table(pd.DataFrame(rows)).loc[0]
    assert not row["loss_direction"] and row["loss_heading"]
    assert row["loss_compass"] and row["needless_fail_compass"]
    assert row["auto_heading_deg"] == 95.0          # the user keeps the raw data


def test_the_oracle_counts_what_a_ranking_in_hindsight_would_lose():
    # calibrate wrote 2.0 against the best fixed fit's 1.0 (a loss); its best eligible
    # candidate scored 1.02 held out (no loss): the ranking lost this case
    rows = _rows("a", "half", 2.0, {"sphere": 1.0})
    rows[0].update(oracle_pct=1.02, oracle_heading_deg=np.nan, oracle_method="sphere")
    # nothing eligible: the oracle keeps the raw data (10 %) and loses too
    none = _rows("b", "half", None, {"sphere": 1.0})
    none[0].update(oracle_pct=np.nan, oracle_heading_deg=np.nan, oracle_method="")
    cases = case_table(pd.DataFrame(rows + none))
    assert cases["loss"].tolist() == [True, True]
    assert cases["loss_oracle"].tolist() == [False, True]
    assert cases["oracle_pct"].tolist() == [1.02, 10.0]
    assert protocol_table(cases).loc[0, "losses_oracle"] == 1


def test_the_recordings_best_fixed_fit_is_chosen_knowing_every_case():
    # recording a: sphere wins one protocol by far and loses the other two narrowly; fang
    # ties every case: fang loses none, sphere two. Recording b: only sphere ties its one case
    rows = (_rows("a", "half", 1.0, {"sphere": 1.0, "fang": 1.2})
            + _rows("a", "blocks", 1.0, {"sphere": 2.0, "fang": 1.0})
            + _rows("a", "band_x", 1.0, {"sphere": 2.0, "fang": 1.0})
            + _rows("b", "half", 1.0, {"sphere": 1.0, "fang": 9.0}))
    cases = case_table(pd.DataFrame(rows))
    assert cases["recording_best"].tolist() == ["fang"] * 3 + ["sphere"]
    assert cases["loss_recording_best"].tolist() == [False] * 4
    assert cases["tied"].tolist() == [2, 1, 1, 1]
    # a third fixed method that loses everywhere changes neither choice
    worse = [dict(r, algorithm="diagonal", spread_pct=r["spread_pct"] * 3) for r in rows
             if r["algorithm"] == "sphere"]
    again = case_table(pd.DataFrame(rows + worse).sort_values(["dataset", "protocol"],
                                                                kind="stable"))
    assert sorted(again["recording_best"]) == ["fang"] * 3 + ["sphere"]
    # with one method per recording, recording a must lose a case: sphere and fang split it
    split = case_table(pd.DataFrame(_rows("a", "half", 1.0, {"sphere": 1.0, "fang": 3.0})
                                    + _rows("a", "blocks", 1.0, {"sphere": 3.0, "fang": 1.0})))
    assert split["loss_recording_best"].sum() == 1
    table = protocol_table(split)
    assert table.set_index("protocol").loc["all", ["losses_recording_best", "one_tied"]
                                           ].tolist() == [1, 2]


def test_a_degenerate_fit_never_is_the_best_in_hindsight():
    rows = _rows("a", "half", 1.0, {"sphere": 1.0, "crassidis": 0.01})
    rows[-1]["degenerate"] = True
    cases = case_table(pd.DataFrame(rows))
    assert cases.loc[0, "best_fixed"] == "sphere" and not cases.loc[0, "loss"]
    assert protocol_table(cases).loc[0, "wtl:crassidis"] == "1/0/0"


def test_tolerance_is_a_quarter_point_or_five_percent():
    assert tolerance(1.0) == 0.25 and tolerance(10.0) == pytest.approx(0.5)
    assert tolerance_deg(5.0) == 1.0 and tolerance_deg(30.0) == pytest.approx(3.0)


def test_one_unit_scores_every_entrant_under_every_protocol(tmp_path):
    rec = rotating(K=1200)
    folder = tmp_path / "spiral"
    folder.mkdir()
    pd.DataFrame({"t": rec.t, "mx": rec.y[:, 0], "my": rec.y[:, 1],
                  "mz": rec.y[:, 2]}).to_csv(folder / "data.csv", index=False)
    study = GeneralisationStudy(str(tmp_path), ["spiral"], ("blocks", "band_z", "half"),
                                ("sphere", "ellipsoid"), peers=False, bootstrap=0)
    out = study.run_unit("spiral")
    rows = pd.DataFrame(out["trials"])
    assert set(rows["protocol"]) == {"blocks", "band_z", "half"}
    assert sorted(rows[rows["protocol"] == "blocks"]["algorithm"]) == \
        sorted([AUTO, "sphere", "ellipsoid"])
    assert len(out["times"]) == len(rows) and out["intervals"] == []
    blocks = rows[rows["protocol"] == "blocks"].set_index("algorithm")
    # the true model is an ellipsoid: the full fit is within the noise, the sphere is not
    assert blocks.loc["ellipsoid", "spread_pct"] < 0.5 * blocks.loc["sphere", "spread_pct"]
    assert blocks.loc[AUTO, "written"] and blocks.loc[AUTO, "status"] in ("PASS", "WARN")
    assert blocks.loc[AUTO, "spread_pct"] <= blocks.loc["ellipsoid", "spread_pct"] + \
        tolerance(blocks.loc["ellipsoid", "spread_pct"])


def test_protocols_are_the_issues():
    assert set(PROTOCOLS) >= {"blocks", "band_x", "band_y", "band_z", "half", "first15",
                              "spikes", "still_first"}


def test_peers_that_need_the_field_given_are_not_entrants():
    from magbench.studies.generalisation import _peers
    from magbench.studies.peers import PEER_NEEDS_FIELD, available_peers

    assert set(_peers()) == set(available_peers()) - set(PEER_NEEDS_FIELD)
    assert "navlib.cal_mag_twostep_hi" in PEER_NEEDS_FIELD


def test_the_interval_checks_first_half_is_the_half_protocols_decision(monkeypatch):
    """The ``half`` protocol fits the first half, as the interval check does: decided once,
    with the interval rows those of a check that decides it again."""
    import magbench.studies.generalisation as gen

    rec = rotating(K=1200)
    rec = Recording("spiral", rec.y, t=np.arange(rec.K) * 0.11, n_rows=rec.K)   # 132 s
    calls = []
    real = gen.decide

    def counted(part, *args, **kwargs):
        calls.append(part.K)
        return real(part, *args, **kwargs)

    monkeypatch.setattr(gen, "decide", counted)
    memo: dict = {}
    rows, _ = gen.evaluate_protocol(rec, "half", fixed=[], peers=False, memo=memo)
    shared = gen.interval_rows(rec, bootstrap=3, memo=memo)
    assert calls == [600, 600]          # the half protocol, then only the second half
    alone = gen.interval_rows(rec, bootstrap=3)
    assert len(calls) == 4 and shared == alone and len(shared) == 3
    assert rows[0]["algorithm"] == AUTO and rows[0]["K_fit"] == 600
