"""navlib's functions beside magbench's reimplementations: known answers and missing peers."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.methods.api import calibrate
from magbench.sources.trajectory import simulate
from magbench.studies import peer_agreement as pa
from magbench.studies.peers import PEER_FITS, fit_peer


def _noise_free(T: np.ndarray, h: np.ndarray) -> pa.Sample:
    traj = simulate(np.random.default_rng(1), T=T, h=h, rate_hz=100.0, duration_s=24.0)
    return pa.Sample("simulated", "noise-free", traj.y, traj.y,
                     {"angular_rate": traj.angular_rate, "time": traj.t})


def test_missing_peer_gives_one_not_installed_row_per_pair(monkeypatch):
    monkeypatch.setattr(pa, "missing_module", lambda name: "navlib")
    rows = pa.peer_agreement(datasets=1, manoeuvres=1)
    assert len(rows) == len(PEER_FITS)
    assert set(rows["status"]) == {"not installed: navlib"}
    summary = pa.summarize_peer_agreement(rows)
    assert (summary["n_ok"] == 0).all()


def test_fang_pair_agrees_to_rounding():
    pytest.importorskip("navlib")
    rows = pa.peer_agreement(["navlib.cal_mag_ellipsoid_fit_fang"], datasets=3)
    assert (rows["status"] == "ok").all()
    assert rows["field_rel"].max() < 1e-9 and rows["h_rel"].max() < 1e-9


def test_magyc_pairs_recover_the_truth_on_noise_free_data():
    pytest.importorskip("navlib")
    T = np.array([[1.1, 0.05, 0.02], [0.05, 0.95, -0.03], [0.02, -0.03, 1.02]])
    h = np.array([0.1, -0.2, 0.05])
    sample = _noise_free(T, h)
    for peer in ("navlib.cal_mag_magyc_ls", "navlib.cal_mag_magyc_nls"):
        _, h_p = fit_peer(peer, sample.y_fit, **sample.inputs)
        ours = calibrate(sample.y_fit, PEER_FITS[peer][2], raw=True, **sample.inputs)
        assert np.abs(ours.h - h).max() < 1e-4          # midpoint derivative
        assert np.abs(h_p - h).max() < 1e-2             # navlib's one-sided derivative
        assert pa.agreement_row(peer, sample)["field_rel"] < 1e-2


def test_sar_ls_difference_is_navlibs_not_the_truths():
    """On noise-free sphere data magbench recovers h; navlib misses it (its normal matrix
    squares the rate's skew matrix element by element): the explained difference."""
    pytest.importorskip("navlib")
    h = np.array([0.1, -0.2, 0.05])
    sample = _noise_free(np.eye(3), h)
    ours = calibrate(sample.y_fit, "sar_ls", raw=True, **sample.inputs)
    _, h_p = fit_peer("navlib.cal_mag_sar_ls", sample.y_fit, **sample.inputs)
    assert np.abs(ours.h - h).max() < 1e-4
    assert np.abs(h_p - h).max() > 0.1


def test_rows_have_the_columns_and_a_gyro_pair_skips_magnetometer_data():
    pytest.importorskip("navlib")
    rows = pa.peer_agreement(["navlib.cal_mag_sar_ls", "navlib.cal_mag_sphere_fit"],
                             datasets=2, manoeuvres=1)
    assert list(rows.columns) == pa.AGREEMENT_COLUMNS
    assert set(rows.loc[rows["peer"] == "navlib.cal_mag_sar_ls", "data"]) == {"simulated"}
    assert set(rows.loc[rows["peer"] == "navlib.cal_mag_sphere_fit", "data"]) == {"synthetic"}
