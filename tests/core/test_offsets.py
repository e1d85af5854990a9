"""An offset that changes within a recording: window offsets, segments, the rows kept."""

from __future__ import annotations

import numpy as np

from magbench.core.offsets import (
    consistent_rows,
    gyro_orientation,
    offset_segments,
    window_offsets,
)
from magbench.sources.trajectory import simulate


def switched(shift: np.ndarray, at: float = 0.55, noise: float = 0.0, seed: int = 3):
    """A 60 s tumble at 50 Hz in a unit field; from ``at`` of the way the field carries an
    extra sensor-frame offset ``shift``."""
    traj = simulate(np.random.default_rng(seed), rate_hz=50.0, duration_s=60.0,
                    mag_noise=noise, gyro_noise=0.1 * noise)
    y = traj.y.copy()
    cut = int(at * len(y))
    y[cut:] += shift
    return traj, y, cut


def test_a_constant_offset_gives_one_segment_and_its_value():
    traj, y, _ = switched(np.zeros(3), noise=0.005)
    y = y + np.array([0.2, -0.1, 0.3])
    windows = window_offsets(traj.t, y, gyro_orientation(traj.t, traj.angular_rate))
    assert windows.turning.mean() > 0.3
    np.testing.assert_allclose(np.nanmedian(windows.offset, axis=0), [0.2, -0.1, 0.3],
                               atol=0.02)
    segments = offset_segments(windows, 0.1)
    assert len(segments) == 1
    keep, _ = consistent_rows(windows, segments, len(y))
    assert keep.all()


def test_an_offset_switched_on_part_way_is_cut_out():
    """Half the field strength added at 33 s: two segments, the cut within a window of the
    switch, and the kept rows all on one side of it."""
    traj, y, cut = switched(np.array([0.0, 0.3, -0.4]), noise=0.005)
    windows = window_offsets(traj.t, y, gyro_orientation(traj.t, traj.angular_rate))
    segments = offset_segments(windows, 0.1)
    assert len(segments) == 2
    boundary = windows.start[segments[1].first]
    assert abs(boundary - cut) <= 2 * (windows.stop[0] - windows.start[0])
    np.testing.assert_allclose(segments[1].offset - segments[0].offset, [0.0, 0.3, -0.4],
                               atol=0.03)
    keep, best = consistent_rows(windows, segments, len(y))
    assert best is segments[0]                      # 55 % of the turning before the switch
    rows = np.flatnonzero(keep)
    assert rows.max() < cut and rows.size > 0.45 * len(y)


def test_a_short_excursion_is_an_outlier_not_a_change():
    """A 2 s disturbance (a magnet passed by) leaves one segment; its windows are set
    aside."""
    traj, y, _ = switched(np.zeros(3), noise=0.005)
    y[1500:1600] += np.array([0.5, 0.0, 0.0])
    windows = window_offsets(traj.t, y, gyro_orientation(traj.t, traj.angular_rate))
    segments = offset_segments(windows, 0.1)
    assert len(segments) == 1 and segments[0].outliers
    keep, _ = consistent_rows(windows, segments, len(y))
    assert not keep[1500:1600].all() and keep.mean() > 0.9


def test_a_jump_at_rest_ends_a_segment():
    """Still for 20 s, the offset changes at 10 s: the still windows' jump cuts there."""
    t = np.arange(0, 20, 0.02)
    y = np.tile([0.5, 0.0, 0.8], (len(t), 1))
    y[len(t) // 2:] += [0.3, 0.0, 0.0]
    windows = window_offsets(t, y, gyro_orientation(t, np.zeros((len(t), 3))))
    assert not windows.turning.any()
    segments = offset_segments(windows, 0.1)
    assert len(segments) == 2


def test_window_offsets_hold_one_window_not_the_recording():
    # A long attitude log: the pair products are formed a window at a time, so the peak is
    # far below one (K, 3, 3) array (72 bytes a row).
    import tracemalloc

    K = 100_000
    t = np.arange(K) * 0.01
    angle = 0.3 * t
    Q = np.zeros((K, 3, 3))
    Q[:, 0, 0] = Q[:, 1, 1] = np.cos(angle)
    Q[:, 0, 1], Q[:, 1, 0] = -np.sin(angle), np.sin(angle)
    Q[:, 2, 2] = 1.0
    field = np.column_stack([np.cos(angle), -np.sin(angle), np.zeros(K)])
    tracemalloc.start()
    windows = window_offsets(t, field, Q)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 0.5 * 72 * K
    assert np.isfinite(windows.jump).all()
