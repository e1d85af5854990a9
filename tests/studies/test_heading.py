"""The heading study at a tiny size: rows, known answers, failures as rows, summaries."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from magbench.core.model import Calibration
from magbench.core.rotations import rotation_exp
from magbench.engine.sweep import run_study
from magbench.methods.registry import register, unregister
from magbench.sources.synthetic import Point
from magbench.sources.trajectory import simulate
from magbench.studies.heading import (
    HEADING_ROW_COLUMNS,
    HeadingStudy,
    correlations,
    heading_rows,
    scored_field,
)
from magbench.studies.review import read_trials

ALGOS = ["sphere", "fang", "magyc_ls"]


def write_recording(root: Path, name: str = "sim", accelerometer: bool = True) -> Path:
    """A simulated recording in the BROAD layout (44 uT, magnetometer 12 ms late)."""
    tr = simulate(np.random.default_rng(0), rate_hz=50.0, duration_s=30.0, rate_rms=1.5,
                  lag_s=0.012, mag_noise=0.002, gyro_noise=0.002)
    columns = {"t": tr.t, **dict(zip(["mx", "my", "mz"], (44.0 * tr.y).T, strict=True)),
               **dict(zip(["gx", "gy", "gz"], tr.angular_rate.T, strict=True)),
               **dict(zip(["qw", "qx", "qy", "qz"], tr.attitude.T, strict=True))}
    if accelerometer:
        columns.update(zip(["ax", "ay", "az"], tr.acceleration.T, strict=True))
    folder = root / name
    folder.mkdir(parents=True)
    pd.DataFrame(columns).to_csv(folder / "data.csv", index=False)
    return root


def tiny(root: Path, **kw) -> HeadingStudy:
    settings = {"algorithms": ALGOS, "trials": 2, "root": str(root), "datasets": ["sim"],
                "distortions": ["eq80"], "draws": 1, "seed": 3, "duration_s": 12.0,
                "max_samples": 600}
    return HeadingStudy(**{**settings, **kw})


def test_the_study_writes_one_row_per_unit_and_method_and_its_summaries(tmp_path):
    spec = tiny(write_recording(tmp_path / "data"))
    assert len(spec.units()) == 2 + 1 + 1
    run_study(spec, tmp_path / "heading", n_jobs=1, chunk_size=1, progress=False)
    trials = read_trials(tmp_path / "heading" / "heading_trials.csv")
    on_disk = pd.read_csv(tmp_path / "heading" / "heading_trials.csv")
    assert list(on_disk.columns) == HEADING_ROW_COLUMNS     # wall times in the sidecar
    times = pd.read_csv(tmp_path / "heading" / "heading_trials_times.csv")
    assert len(times) == len(on_disk) and (times["time_s"] >= 0).all()
    assert len(trials) == len(spec.units()) * len(ALGOS) and trials["ok"].all()
    assert set(trials["gauge"]) == {"symmetric", "returned"}
    spec.summarize(tmp_path / "heading")
    summary = pd.read_csv(tmp_path / "heading" / "summary.csv")
    assert set(summary["part"]) == {"mc", "semi", "given"} and set(summary["n"]) <= {1, 2}
    corr = pd.read_csv(tmp_path / "heading" / "correlation.csv")
    assert {"mc", "semi", "given"} == set(corr["part"])
    mc = trials[trials["part"] == "mc"]
    # the bound is a floor for methods that know nothing more than the magnitude
    assert (mc["heading_rms"] >= mc["crb_heading"]).all()
    assert (abs(mc["lag_ms"] - mc["lag_true_ms"]) < 0.3 * 1000 / spec.rate_hz).all()
    semi = trials[trials["part"] == "semi"]
    assert (semi["mount_deg"] == 3.0).all() and semi["J"].notna().all()
    assert (abs(semi["lag_ms"] - 12.0) < 2.0).all() and (abs(semi["gyro_lag_ms"]) < 2.0).all()
    assert trials[trials["part"] == "given"]["J"].isna().all()


def test_noise_free_and_aligned_a_magnitude_fit_has_no_heading_error(tmp_path):
    exact = HeadingStudy(algorithms=["fang"], parts=["mc"], trials=1, seed=5, sigma=0.0,
                         gyro_noise=0.0, accel_noise=0.0, lag_max_s=0.0, mount_max_deg=0.0,
                         correct_lag=False,
                         point=Point(beta=0.0), duration_s=12.0)
    row = heading_rows(exact, "mc", "", "", 0)[0]
    assert row["ok"] and row["J"] < 1e-8 and row["heading_rms"] < 1e-3
    # the same manoeuvre mounted 10 degrees off: the magnitude cannot see it, the heading can
    mounted = HeadingStudy(**{**exact.__dict__, "mount_max_deg": 10.0})
    row = heading_rows(mounted, "mc", "", "", 0)[0]
    assert row["J"] < 1e-8 and row["heading_rms"] > 0.1 * row["mount_deg"]


def test_a_method_needing_an_input_the_part_lacks_gives_a_row_with_the_reason(tmp_path):
    root = write_recording(tmp_path / "data", accelerometer=False)

    @register("needs_accel_probe", label="probe", min_samples=10, family="extra")
    def probe(samples, *, acceleration):
        return Calibration(np.eye(3), np.zeros(3))

    try:
        spec = tiny(root, algorithms=["needs_accel_probe", "sphere"], parts=["given"])
        rows = {r["algorithm"]: r for r in heading_rows(spec, "given", "sim", "", 0)}
    finally:
        unregister("needs_accel_probe")
    assert not rows["needs_accel_probe"]["ok"]
    assert "needs acceleration" in rows["needs_accel_probe"]["error"]
    assert rows["sphere"]["ok"]


def test_scored_field_keeps_a_returned_rotation_only_when_asked():
    R = rotation_exp(np.array([0.0, 0.0, 0.2]))
    cal = Calibration(1.1 * R, np.array([0.1, 0.0, 0.0]))
    y = np.random.default_rng(1).normal(size=(20, 3))
    assert np.allclose(scored_field(cal, y, True), cal.apply(y))
    assert np.allclose(scored_field(cal, y, False), (y - cal.h) / 1.1)
    # an alignment to the inertial axes turns the symmetric gauge's field
    aligned = SimpleNamespace(T=cal.T, h=cal.h, alignment=R.T)
    assert np.allclose(scored_field(aligned, y, False), (y - cal.h) / 1.1 @ R)


def test_correlations_rank_per_dataset_and_pooled():
    frame = pd.DataFrame({"part": "semi", "dataset": ["a"] * 4 + ["b"] * 4, "ok": True,
                          "heading_rms": [1, 2, 3, 4, 1, 2, 3, 4],
                          "J": [0.1, 0.2, 0.3, 0.4, 4, 3, 2, 1], "J_r": [1.0] * 8})
    c = correlations(frame).set_index("dataset")
    assert c.loc["a", "spearman_J"] == pytest.approx(1.0)
    assert c.loc["b", "spearman_J"] == pytest.approx(-1.0)
    assert c.loc["pooled", "n_J"] == 8 and np.isnan(c.loc["a", "spearman_J_r"])


def test_a_recording_that_cannot_be_prepared_gives_each_method_a_row_with_the_reason(
        monkeypatch):
    import magbench.studies.heading as heading

    def no_lag(*args, **kwargs):
        raise ValueError("phone: no lag found within 0.1 s")

    monkeypatch.setattr(heading, "_prepared", no_lag)
    spec = heading.HeadingStudy(root="nowhere", datasets=["phone"], algorithms=["sphere", "fang"])
    rows = heading.heading_rows(spec, "given", "phone", "", 0)
    assert [r["algorithm"] for r in rows] == ["sphere", "fang"]
    assert all(not r["ok"] and r["error"] == "not prepared: phone: no lag found within 0.1 s"
               for r in rows)
    assert set(rows[0]) >= set(heading.HEADING_ROW_COLUMNS)


def test_a_prepared_recording_is_kept_and_recomputed_when_its_file_or_options_change(
        tmp_path, monkeypatch):
    import magbench.studies.heading as heading

    root, cache = write_recording(tmp_path / "data"), tmp_path / "prepared"
    calls = []

    def counted(rec, **kw):
        calls.append(kw)
        return heading.prepare.__wrapped__(rec, **kw)

    counted.__wrapped__ = heading.prepare
    monkeypatch.setattr(heading, "prepare", counted)

    def get(tolerance=0.1, where=cache):
        heading._prepared_or_reason.cache_clear()     # a new process: only the disk remembers
        return heading._prepared(str(root), "sim", tolerance, True,
                                 None if where is None else str(where))

    direct, kept = get(where=None), get()
    assert len(calls) == 2 and len(list(cache.glob("sim-*.npz"))) == 1
    again = get()
    assert len(calls) == 2                                # read back, not prepared again
    for p in (kept, again):                               # the very same numbers
        for k in heading._REC_ARRAYS:
            a, b = getattr(direct.rec, k), getattr(p.rec, k)
            assert a.tobytes() == b.tobytes() and a.dtype == b.dtype and a.shape == b.shape
        for k in ("reference", "clean", "movement"):
            assert getattr(direct, k).tobytes() == getattr(p, k).tobytes()
        assert (p.lag_s, p.gyro_lag_s, p.mag_gyro_lag_s, p.strength) == (
            direct.lag_s, direct.gyro_lag_s, direct.mag_gyro_lag_s, direct.strength)
    first = next(cache.glob("sim-*.npz")).read_bytes()
    get(tolerance=0.2)                                    # another option: prepared again
    assert len(calls) == 3 and calls[-1]["tolerance"] == 0.2
    get()
    assert len(calls) == 4                                # the other key's file was replaced
    assert next(cache.glob("sim-*.npz")).read_bytes() == first      # same bytes every time
    data = pd.read_csv(root / "sim" / "data.csv")
    data.loc[100, "mx"] += 1.0                            # the recording changed: one sample
    data.to_csv(root / "sim" / "data.csv", index=False)
    changed = get()
    assert len(calls) == 5 and not np.array_equal(changed.rec.y, direct.rec.y)
    assert len(list(cache.glob("sim-*.npz"))) == 1


def test_a_recording_that_cannot_be_prepared_is_kept_with_its_reason(tmp_path, monkeypatch):
    import magbench.studies.heading as heading

    root, calls = write_recording(tmp_path / "data"), []

    def no_lag(rec, **kw):
        calls.append(rec.name)
        raise ValueError(f"{rec.name}: no lag found within 0.1 s")

    monkeypatch.setattr(heading, "prepare", no_lag)
    for _ in range(2):
        heading._prepared_or_reason.cache_clear()
        with pytest.raises(ValueError, match=r"^sim: no lag found within 0\.1 s$"):
            heading._prepared(str(root), "sim", 0.1, True, str(tmp_path / "prepared"))
    assert calls == ["sim"]
