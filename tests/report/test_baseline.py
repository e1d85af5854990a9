"""The baseline section: the metric's explanation, the printed formulas, the efficiency."""

import numpy as np
import pandas as pd
import pytest

from magbench.core.metrics import accuracy_cost
from magbench.report import baseline as report
from tests.report.helpers import rb_sweep


def test_metric_hypotheses_on_hand_made_rows():
    rows = pd.DataFrame({"algorithm": ["magical"] * 2, "meaningful": [True, True],
                         "J": [0.1, 0.3], "sq_err": [0.01, 0.03], "crb_J": [0.2, 0.2],
                         "crb": [0.01, 0.03]})
    hyp = report.metric_hypotheses(rows).iloc[0]
    assert hyp["inv_mean_J"] == pytest.approx(5.0)
    assert hyp["inv_mean_J2"] == pytest.approx(1 / 0.05)
    assert hyp["inv_mean_sq"] == pytest.approx(50.0)
    assert hyp["inv_crb"] == pytest.approx(50.0)
    assert hyp["crb_floor"] == pytest.approx(5.0)
    assert hyp["paper"] == pytest.approx(2.28e5)
    assert np.isclose(hyp["paper_over_sq"], 2.28e5 / 50)


def test_top_share_is_a_paired_bootstrap_of_the_squared_metric():
    rng = np.random.default_rng(1)
    err = rng.gamma(2.0, 1e-6, 250)
    rows = [{"trial": i, "algorithm": name, "sq_err": e * f}
            for i, e in enumerate(err) for name, f in (("magical", 1.0), ("wu_shi", 1.2))]
    text = report._top_share(pd.DataFrame(rows), ["magical", "wu_shi"])
    # On the same datasets magical's error is always 1.2 times smaller: first in every draw.
    assert "MAG.I.C.AL 100 %" in text and "the first place is significant" in text
    rows += [{"trial": i, "algorithm": "dorveaux", "sq_err": e * (1 + 0.3 * rng.standard_normal())}
             for i, e in enumerate(err)]
    text = report._top_share(pd.DataFrame(rows), ["magical", "dorveaux"])
    assert "not significant" in text


def test_printed_bias_cost_is_recomputed_from_the_estimates():
    T_true, h_true = np.diag([1.1, 0.9, 1.0]), np.array([0.1, -0.05, 0.02])
    T_est = T_true + 0.001 * np.eye(3)
    h_est = h_true + 0.001
    row = {"algorithm": "twostep", "meaningful": True, "trial": 0}
    row.update({f"h_{i}": h_est[i] for i in range(3)})
    row.update({f"T_{i}{j}": T_est[i, j] for i in range(3) for j in range(3)})
    row.update({f"h_true_{i}": h_true[i] for i in range(3)})
    row.update({f"T_true_{i}{j}": T_true[i, j] for i in range(3) for j in range(3)})
    J, J_h, J_T = accuracy_cost(T_est, h_est, T_true, h_true)
    row.update({"J": J, "J_h": J_h, "J_T": J_T})
    cost = report.printed_bias_cost(pd.DataFrame([row])).iloc[0]
    Jp, Jp_h, Jp_T = accuracy_cost(T_est, np.linalg.solve(T_est, h_est), T_true, h_true)
    assert cost["factor_J"] == pytest.approx(Jp / J)
    assert cost["factor_sq"] == pytest.approx((Jp_h ** 2 + Jp_T ** 2) / (J_h ** 2 + J_T ** 2))
    assert cost["factor_sq"] > cost["factor_J"] > 1
    text = report.printed_bias_sentence(pd.DataFrame([cost]))
    assert f"x{cost['factor_J']:.2g} in J and x{cost['factor_sq']:.2g} in the squared" in text


def test_printed_vasconcelos_collapse_with_bias_is_set_beside_table4():
    values = [0.05, 0.5, 1.0]
    base = rb_sweep("K", [300], {})
    base = pd.concat([base, base[base["algorithm"] == "vasconcelos"].assign(
        algorithm="vasconcelos_printed", RB_pct=99.6, n_meaningful=249)])

    def sweep(x, printed):
        s = rb_sweep(x, values, {})
        v = s[s["algorithm"] == "vasconcelos"].assign(algorithm="vasconcelos_printed")
        v["RB_pct"] = printed
        v["n_meaningful"] = (v["RB_pct"] * 2.5).round().astype(int)
        return pd.concat([s, v])

    text = report.printed_robustness(base, sweep("gamma", [100, 27, 14.4]),
                                     sweep("beta", [100, 80, 32.4]))
    assert "rests on 1 failed run of 250" in text and "99.6 % [97.8, 99.9]" in text
    assert "explain the review's fall with beta" in text
    # The review's Table 4 gives Vasconcelos its lowest robustness mark: the collapse with
    # bias agrees with it (issue 41), it is not a contradiction.
    assert "collapse with bias too, as the review's Table 4 (1 robustness mark" in text
    assert "the explanation holds for both" in text and "never reports" not in text
    text = report.printed_robustness(base, sweep("gamma", [100, 100, 99.2]),
                                     sweep("beta", [100, 80, 32.4]))
    assert "leave it robust to bias" in text


def test_why_paragraph_takes_every_paper_number_from_paper_values():
    rows = [{"algorithm": n, "meaningful": True, "trial": 0, "J": 2.5e-3, "sq_err": 4e-6,
             "crb_J": 2.5e-3, "crb": 4e-6} for n in report.REVIEW]
    trials = pd.DataFrame(rows)
    context = report._why_context(trials, report.metric_hypotheses(trials))
    # Table 2's five accurate methods: 2.26e5 (Dorveaux) to 2.32e5 (Wu-Shi), median 2.28e5.
    assert (context["paper_lo"], context["paper_hi"]) == ("2.26e5", "2.32e5")
    assert (context["paper_typical"], context["paper_J"]) == ("2.28e5", "4.4e-6")
    assert (context["twostep_paper"], context["ekf_paper"]) == ("35.3", "3.31e3")
    assert context["n_accurate"] == "five" and context["paper_over_floor"] == "5.7e+02"


def test_baseline_section_is_table2_and_the_efficiency_table(tmp_path):
    assert report.baseline_section(tmp_path) == ""
    (tmp_path / "baseline").mkdir()
    rb_sweep("K", [300], {}).to_csv(tmp_path / "baseline" / "summary.csv", index=False)
    text = report.baseline_section(tmp_path)
    assert text.startswith("## Baseline (Table 2)\n\n*Run: no `baseline/run.json`")
    assert "| MAG.I.C.AL | 400 | 2.28e+05 | 0.0018 | 100 [98.5, 100] | 100 |" in text
    assert "Efficiency at the baseline" in text and "### Why" not in text   # no trials.csv


def test_rankings_show_ties_at_the_printed_precision():
    table = pd.DataFrame({"v": [2.32e5, 2.28e5, 2.28e5, 2.27e5]},
                         index=["wu_shi", "magical", "vasconcelos", "ali"])
    assert report._ranking(table, "v") == "Wu-Shi > MAG.I.C.AL = Vasconcelos > Ali PSO"
