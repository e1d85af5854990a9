"""Wu and Shi's simulation study (section IV): data, error metrics, divergence, verdicts, run."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from magbench.cli import main
from magbench.methods.api import calibrate
from magbench.report.wushi import (
    verdict_convergence,
    verdict_divergence,
    verdict_ml_better,
    verdict_time_ratio,
    wushi_report_section,
)
from magbench.sources.wushi_sim import attitude_angles, attitude_matrices, simulate, truth
from magbench.studies.wushi import (
    ML,
    NM,
    count_divergences,
    decompose,
    divergence_table,
    error_metrics,
    gauge_R,
    iterations_to_converge,
    refine_unit,
)


def rotation(axis: int, angle: float) -> np.ndarray:
    """Right-handed active rotation about coordinate axis 0, 1 or 2."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


def random_orthogonal(rng: np.random.Generator) -> np.ndarray:
    Q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    return Q


# ---------------------------------------------------------------------------------- data

def test_attitude_matrices_are_rotations_and_match_an_independent_euler_product():
    N = 41
    C = attitude_matrices(N)
    phi, psi, theta = attitude_angles(N)
    assert np.allclose(np.einsum("kji,kjl->kil", C, C), np.eye(3), atol=1e-14)
    assert np.allclose(np.linalg.det(C), 1.0, atol=1e-14)
    # The printed matrix is R_y(psi) R_z(theta) R_x(phi) (y is "Up", the yaw axis).
    for k in range(N):
        expected = rotation(1, psi[k]) @ rotation(2, theta[k]) @ rotation(0, phi[k])
        assert np.allclose(C[k], expected, atol=1e-14)
    # The angles of section IV at k = N: phi = 20 deg, psi = 360 deg, theta = 0.
    assert np.rad2deg([phi[-1], psi[-1], theta[-1]]) == pytest.approx([20.0, 360.0, 0.0],
                                                                       abs=1e-9)


def test_noise_free_data_satisfy_the_model_exactly():
    data = simulate(np.random.default_rng(1), N=60, sigma=0.0)
    m_n, S, h = truth()
    assert np.linalg.norm(m_n) == pytest.approx(1.0, abs=1e-15)
    assert np.allclose(data.m, data.C @ m_n, atol=1e-15)
    assert np.allclose(np.linalg.norm(data.m, axis=1), 1.0, atol=1e-14)
    assert np.allclose(data.y, data.m @ S.T + h, atol=1e-14)
    noisy = simulate(np.random.default_rng(1), N=60, sigma=0.003)
    assert np.std(noisy.y - data.y) == pytest.approx(0.003, rel=0.2)


# ------------------------------------------------------------------------------- metrics

@pytest.fixture
def S_h():
    _, S, h = truth()
    return S, h


def test_metrics_are_zero_for_the_truth_and_any_orthogonal_gauge(S_h):
    S, h = S_h
    rng = np.random.default_rng(2)
    for T in (S, S @ random_orthogonal(rng), S @ np.diag([1.0, -1.0, 1.0])):
        e = error_metrics(T, h, S, h)
        assert e["e_s"] == pytest.approx(0.0, abs=1e-10)
        assert e["e_o"] == pytest.approx(0.0, abs=1e-10)
        assert e["e_h"] == 0.0


def test_gauge_step_is_invariant_to_T_Q_and_gives_positive_upper_triangular_R():
    rng = np.random.default_rng(3)
    for _ in range(5):
        T = rng.standard_normal((3, 3)) + 2.0 * np.eye(3)
        R = gauge_R(T)
        assert np.all(np.tril(R, -1) == 0.0) and np.all(np.diag(R) > 0)
        Q = np.linalg.inv(T) @ np.linalg.inv(R)            # T^-1 = Q R: Q is orthogonal
        assert np.allclose(Q.T @ Q, np.eye(3), atol=1e-12)
        assert np.allclose(gauge_R(T @ random_orthogonal(rng)), R, atol=1e-12)
    # An upper-triangular T with positive diagonal is already in the gauge: R = T^-1.
    U = np.triu(rng.standard_normal((3, 3))) + 3.0 * np.eye(3)
    assert np.allclose(gauge_R(U), np.linalg.inv(U), atol=1e-14)


def test_decompose_gives_unit_diagonal_M():
    R = np.array([[2.0, 0.3, -0.1], [0.0, 1.5, 0.2], [0.0, 0.0, 0.7]])
    lam, M = decompose(R)
    assert np.allclose(lam, [2.0, 1.5, 0.7])
    assert np.allclose(np.diag(M), 1.0)
    assert np.allclose(M @ np.diag(lam), R)


def test_e_s_of_a_one_percent_scale_error(S_h):
    S, h = S_h
    # T = S / 1.01 scales R (and every Lambda entry) by 1.01: e_s = sqrt(3) * 1 % / 3.
    e = error_metrics(S / 1.01, h, S, h)
    assert e["e_s"] == pytest.approx(100.0 * np.sqrt(3.0) * 0.01 / 3.0, rel=1e-9)
    assert e["e_o"] == pytest.approx(0.0, abs=1e-10)
    # One axis only: Lambda_33 * 1.01, M unchanged: e_s = 1 % / 3.
    R = gauge_R(S) @ np.diag([1.0, 1.0, 1.01])
    e = error_metrics(np.linalg.inv(R), h, S, h)
    assert e["e_s"] == pytest.approx(100.0 * 0.01 / 3.0, rel=1e-9)
    assert e["e_o"] == pytest.approx(0.0, abs=1e-10)


def test_e_o_of_a_known_M_perturbation_and_e_h_of_a_known_offset(S_h):
    S, h = S_h
    lam, M = decompose(gauge_R(S))
    delta = 0.01
    M2 = M.copy()
    M2[0, 1] += delta
    T = np.linalg.inv(M2 @ np.diag(lam))
    e = error_metrics(T, h + np.array([0.03, 0.0, 0.04]), S, h)
    assert e["e_o"] == pytest.approx(180.0 / (3.0 * np.pi) * delta, rel=1e-9)
    assert e["e_s"] == pytest.approx(0.0, abs=1e-10)
    assert e["e_h"] == pytest.approx(0.05 / 3.0, rel=1e-12)


def test_wu_shi_recovers_noise_free_data_in_these_metrics():
    data = simulate(np.random.default_rng(4), N=300, sigma=0.0)
    for name in (ML, NM):
        cal = calibrate(data.y, name)
        e = error_metrics(cal.T, cal.h, data.S, data.h)
        assert max(e["e_s"], e["e_o"], e["e_h"]) < 1e-7


def test_refine_unit_on_normalised_data_equals_calibrate():
    """The study's direct refine calls normalise the data exactly as calibrate does."""
    from magbench.methods.algorithms._wu_shi_init import initial_estimate, upper_inverse
    from magbench.methods.api import unit_scale

    data = simulate(np.random.default_rng(5), N=300, sigma=0.003)
    scale = unit_scale(data.y)
    assert scale == 4.0
    T0, h0 = initial_estimate(data.y / scale)
    R0, h0 = upper_inverse(T0) / scale, h0 * scale
    for name in (ML, NM):
        T, h, history, converged = refine_unit(name, data.y, R0, h0, 50)
        cal = calibrate(data.y, name, raw=True)
        assert converged
        assert np.allclose(T, cal.T, rtol=1e-10, atol=1e-12)
        assert np.allclose(h, cal.h, rtol=1e-10, atol=1e-12)
    # ML history (4) in gauss^2: zero at x(0), then about (N - 9/...) sigma^2 per sample.
    _, _, history, _ = refine_unit(ML, data.y, R0, h0, 50)
    assert history[0] < 1e-20
    assert 0.5 * 300 * 0.003 ** 2 < history[-1] < 2.0 * 300 * 0.003 ** 2


# ---------------------------------------------------------- convergence and divergence

def test_iterations_to_converge_on_hand_made_histories():
    assert iterations_to_converge([0.0, 5.0, 3.0000001, 3.0, 3.0]) == 2
    assert iterations_to_converge([0.0, 5.0, 3.1, 3.0, 3.0]) == 3
    assert iterations_to_converge([2.0, 2.0, 2.0]) == 0
    assert iterations_to_converge([1.0, 0.0, 0.0]) == 1


def test_count_divergences_above_threshold_and_failures():
    assert count_divergences([0.001, 0.005, np.nan, 0.004], 0.004) == 2
    assert count_divergences([], 0.004) == 0


def test_divergence_table_counts_per_alpha():
    rows = [{"alpha_pct": a, "run": r, "method": m, "final_objective": f}
            for a, r, m, f in [(0, 0, "ML", 0.003), (0, 1, "ML", 0.003), (0, 0, "NM", 0.01),
                               (0, 1, "NM", 0.02), (3, 0, "ML", 0.005), (3, 1, "ML", 0.002),
                               (3, 0, "NM", np.nan), (3, 1, "NM", 0.05)]]
    div = divergence_table(pd.DataFrame(rows), {"ML": 0.004, "NM": 0.018})
    assert div["alpha_pct"].tolist() == [0.0, 3.0]
    assert div["runs"].tolist() == [2, 2]
    assert div["ML_divergences"].tolist() == [0, 1]
    assert div["NM_divergences"].tolist() == [1, 2]
    assert div["NM_failed"].tolist() == [0, 1]


# ------------------------------------------------------------------------------ verdicts

def divergence_counts(ml: list[int], nm: list[int], runs: int = 50) -> pd.DataFrame:
    return pd.DataFrame({"alpha_pct": [float(a) for a in range(len(ml))], "runs": runs,
                         "ML_divergences": ml, "NM_divergences": nm})


def test_verdict_divergence():
    paper_like = divergence_counts([0, 0, 0, 0, 0, 0, 2, 5], [0, 3, 15, 30, 40, 45, 50, 50])
    assert verdict_divergence(paper_like)[0] == "holds"
    half_at_3 = divergence_counts([0, 0, 0, 0, 0, 0, 2, 5], [0, 3, 15, 25, 40, 45, 50, 50])
    verdict, evidence = verdict_divergence(half_at_3)
    assert verdict == "partly" and "(25/50)" in evidence
    ml_worse = divergence_counts([0, 5, 9, 9, 9, 9, 9, 9], [0, 1, 2, 3, 4, 5, 6, 7])
    assert verdict_divergence(ml_worse)[0] == "does not hold"


def test_verdict_time_ratio_uses_the_N_nearest_1000():
    times = pd.DataFrame({"N": [100, 900, 3000], "ml_time_s": [1.0, 10.0, 50.0],
                          "nm_time_s": [1.0, 1.0, 1.0]})
    times["ml_over_nm"] = times["ml_time_s"] / times["nm_time_s"]
    verdict, evidence = verdict_time_ratio(times)
    assert verdict == "holds" and "N = 900" in evidence
    times["ml_time_s"] = [1.0, 2.2, 3.0]
    times["ml_over_nm"] = times["ml_time_s"]
    assert verdict_time_ratio(times)[0] == "partly"
    times["ml_over_nm"] = [1.0, 0.8, 1.0]
    assert verdict_time_ratio(times)[0] == "does not hold"


def histories(settle_nm: list[int]) -> pd.DataFrame:
    """ML runs settle at iteration 2; NM run i flat from iteration settle_nm[i]."""
    rows = []
    for run, settle in enumerate(settle_nm):
        for it, f in enumerate([0.0, 0.003, 0.0025, 0.0025, 0.0025]):
            rows.append({"method": "ML", "run": run, "iteration": it, "objective": f})
        nm = [0.02 - 0.001 * i for i in range(settle)] + [0.01] * 2
        for it, f in enumerate(nm):
            rows.append({"method": "NM", "run": run, "iteration": it, "objective": f})
    return pd.DataFrame(rows)


def test_verdict_convergence():
    assert verdict_convergence(histories([1] * 10))[0] == "holds"
    verdict, evidence = verdict_convergence(histories([1] * 9 + [7]))
    assert verdict == "partly" and "NM: 9/10" in evidence and "max 7" in evidence
    assert verdict_convergence(histories([1] * 5 + [8] * 5))[0] == "does not hold"


def test_verdict_ml_better():
    table = pd.DataFrame({"algorithm": [ML, NM], "e_s_mean": [0.06, 0.07],
                          "e_s_std": [0.03, 0.04], "e_o_mean": [0.08, 0.09],
                          "e_o_std": [0.04, 0.05]})
    assert verdict_ml_better(table)[0] == "holds"
    table.loc[0, "e_o_std"] = 0.06
    assert verdict_ml_better(table)[0] == "partly"
    table.loc[0, ["e_s_mean", "e_s_std", "e_o_mean"]] = [1.0, 1.0, 1.0]
    assert verdict_ml_better(table)[0] == "does not hold"


# ---------------------------------------------------------------------------- end to end

def test_study_runs_end_to_end_at_a_tiny_size(tmp_path):
    assert main(["sweep=wushi", f"results_dir={tmp_path}", "trials=2", "sweep.N=60",
                 f"algorithms=[{ML},{NM},sphere,fang]", "sweep.alphas_pct=[0,3]",
                 "sweep.time_N=[30,60]", "sweep.time_repeats=1", "sweep.time_calls=1",
                 "sweep.control_runs=1", "n_jobs=1", "progress=false"]) == 0
    folder = tmp_path / "wushi"
    for name in ("runs.csv", "table1.csv", "settings.csv", "fig3_objective.csv",
                 "fig3_objective.png", "fig5_time.csv", "fig5_time.png", "fig6_divergence.csv",
                 "fig6_divergence.png", "perturbation_runs.csv", "claims.csv", "wushi.md"):
        assert (folder / name).stat().st_size > 0, name
    table = pd.read_csv(folder / "table1.csv")
    assert table["algorithm"].tolist() == [ML, NM, "sphere", "fang", "crb"]
    assert table.loc[table["algorithm"] == ML, "paper_e_s_mean"].item() == 0.0662
    runs = pd.read_csv(folder / "runs.csv")
    assert len(runs) == 2 * 4 + 4                        # + the control on run 0
    history = pd.read_csv(folder / "fig3_objective.csv")
    assert set(history["method"]) == {"ML", "NM"} and set(history["run"]) == {0, 1}
    ml0 = history[(history["method"] == "ML") & (history["iteration"] == 0)]["objective"]
    assert (ml0 < 1e-20).all()                           # m_k(0) fit the data exactly (9)
    div = pd.read_csv(folder / "fig6_divergence.csv")
    assert div["alpha_pct"].tolist() == [0.0, 3.0] and (div["runs"] == 2).all()
    assert div.loc[0, "ML_divergences"] == 0 and div.loc[0, "NM_divergences"] == 0
    claims = pd.read_csv(folder / "claims.csv")
    assert len(claims) == 4
    assert set(claims["verdict"]) <= {"holds", "partly", "does not hold"}
    text = wushi_report_section(tmp_path)
    assert "### Table I" in text and "wushi/fig6_divergence.png" in text
    assert "efficient estimator (Cramer-Rao bound)" in text


def test_report_section_without_results(tmp_path):
    assert "No results yet" in wushi_report_section(tmp_path)


def test_cli_dispatches_kind_wushi(tmp_path, capsys):
    args = ["sweep=wushi", f"results_dir={tmp_path}", "trials=1", "sweep.N=40",
            "sweep.time_N=[40]", "sweep.alphas_pct=[0]", "sweep.time_repeats=1",
            "sweep.time_calls=1", "sweep.control_runs=0", "algorithms=[wu_shi,wu_shi_nm]",
            "n_jobs=1", "progress=false"]
    assert main(args) == 0
    assert (tmp_path / "wushi" / "wushi.md").exists()
    assert "sweep wushi: 2 rows" in capsys.readouterr().out    # ML and NM on one run
    assert main(["sweep=wushi", f"results_dir={tmp_path}", "trials=0"]) == 2
    assert "trials must be an integer >= 1" in capsys.readouterr().err
