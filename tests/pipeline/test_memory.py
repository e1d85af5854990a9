"""``calibrate``'s memory on long recordings (issue 40): under four times the samples' bytes.

The recording is read and calibrated as a long one is: the chunked CSV reader (not the small
file's NumPy path) and blocks far shorter than the recording, so every step that sees all the
samples works as it does on 10 million rows. The costs that do not grow with the recording are
made small as well: the candidates fit ``max_samples`` samples and the geometry check an even
stride of ``GEOMETRY_SAMPLES``, both fixed on a long recording. tracemalloc counts NumPy's and
Python's allocations, not LAPACK's own work arrays (the RSS figures of docs/reliability.md do).
"""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from magbench.core import geometry, robust
from magbench.core.geometry import sphere_fit
from magbench.pipeline.calibration import calibrate_recording
from magbench.sources import recordings
from magbench.sources.recordings import read_samples

#: The bound of docs/reliability.md: peak bytes per byte of samples (K x 3 x 8).
PER_SAMPLE_BYTE = 4.0
ROWS = 200_000


def _write(path: Path, n: int, seed: int = 40) -> Path:
    """A ``t,mx,my,mz`` CSV of a turned sensor with hard and soft iron and noise."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    y = u @ np.array([[52.0, 1.5, -0.8], [0.0, 47.0, 1.1], [0.0, 0.0, 50.0]]).T \
        + [12.0, -7.0, 3.5] + rng.normal(scale=0.3, size=(n, 3))
    np.savetxt(path, np.column_stack([0.01 * np.arange(n), y]), fmt="%.4f", delimiter=",",
               header="t,mx,my,mz", comments="")
    return path


@pytest.fixture
def long_recording_regime(monkeypatch):
    monkeypatch.setattr(geometry, "BLOCK_ROWS", 4096)
    monkeypatch.setattr(robust, "BLOCK_ROWS", 4096)
    monkeypatch.setattr(recordings, "CHUNK_ROWS", 10_000)
    monkeypatch.setattr(recordings, "PLAIN_MAX_BYTES", 0)
    monkeypatch.setattr(recordings, "GEOMETRY_SAMPLES", 2000)


def test_reading_and_calibrating_take_under_four_times_the_samples(tmp_path,
                                                                   long_recording_regime):
    # Measured: read 2.0, read and calibrate 2.8 times (the samples and their times are 1.33;
    # then the screen's residuals, their inliers' copy and the outlier test's deviations).
    path = _write(tmp_path / "long.csv", ROWS)
    read_samples(_write(tmp_path / "warm.csv", 5000))          # imports and caches
    tracemalloc.start()
    try:
        rec = read_samples(path)
        read_peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.reset_peak()
        result = calibrate_recording(rec, ["sphere"], bootstrap=0, max_samples=200)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert rec.K == ROWS and result.chosen is not None and result.work.K <= 200
    assert read_peak < 2.5 * rec.y.nbytes
    assert peak < PER_SAMPLE_BYTE * rec.y.nbytes


def test_the_sphere_fit_of_many_blocks_holds_one_block(monkeypatch):
    # The whole design matrix [2 z, 1] and its right-hand side alone are 1.67 times the
    # samples' bytes (and lstsq copies them again, outside tracemalloc's count).
    monkeypatch.setattr(geometry, "BLOCK_ROWS", 4096)
    rng = np.random.default_rng(1)
    y = rng.normal(size=(ROWS, 3)) * 50.0 + [12.0, -7.0, 3.5]
    rows = rng.random(ROWS) < 0.9
    sphere_fit(y[:10_000])
    tracemalloc.start()
    try:
        sphere_fit(y)
        sphere_fit(y, rows)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 0.25 * y.nbytes
