import math

import numpy as np
import pytest

from magbench.core.geometry import (
    COVERAGE_ANGLE_DEG,
    COVERAGE_GRID,
    coverage,
    fibonacci_sphere,
    largest_gap,
    unit_rows,
)


def _cap(rng, K, half_angle_deg, axis=(0.0, 0.0, 1.0)):
    """K directions uniform on a cap of the given half-angle about ``axis``."""
    z = rng.uniform(math.cos(math.radians(half_angle_deg)), 1.0, K)
    phi = rng.uniform(0, 2 * np.pi, K)
    d = np.column_stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z])
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    # rotate +z onto the axis (Rodrigues), so caps point anywhere
    v, c = np.cross([0.0, 0.0, 1.0], a), a[2]
    if np.linalg.norm(v) < 1e-12:
        return d if c > 0 else -d
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    R = np.eye(3) + vx + vx @ vx / (1 + c)
    return d @ R.T


def _brute_nearest(directions, grid):
    return np.max(fibonacci_sphere(grid) @ unit_rows(directions).T, axis=1)


SETS = [("sphere", 20_000, 180.0), ("sphere", 3000, 180.0), ("cap", 12_000, 60.0),
        ("cap", 5000, 30.0), ("cap", 9000, 100.0), ("few", 24, 180.0), ("one", 1, 180.0)]


@pytest.mark.parametrize(("kind", "K", "half_angle"), SETS)
def test_coverage_and_gap_equal_the_comparison_with_every_sample(kind, K, half_angle):
    rng = np.random.default_rng(K)
    d = 3.0 * _cap(rng, K, half_angle, axis=rng.standard_normal(3))
    nearest = _brute_nearest(d, COVERAGE_GRID)
    expected = float(np.mean(nearest >= math.cos(math.radians(COVERAGE_ANGLE_DEG))))
    assert coverage(d) == expected
    nearest = _brute_nearest(d, 2000)
    radius, centre = largest_gap(d)
    worst = int(np.argmin(nearest))
    assert radius == math.degrees(math.acos(min(1.0, float(nearest[worst]))))
    assert np.array_equal(centre, fibonacci_sphere(2000)[worst])


def test_coverage_and_gap_of_known_shapes():
    rng = np.random.default_rng(1)
    assert coverage(_cap(rng, 20_000, 180.0)) == 1.0
    hemisphere = _cap(rng, 20_000, 90.0)
    assert coverage(hemisphere) == pytest.approx(0.5 + 0.5 * math.sin(math.radians(30)),
                                                 abs=0.03)
    radius, centre = largest_gap(hemisphere)
    assert radius == pytest.approx(90.0, abs=3.0) and centre[2] < -0.99
    radius, centre = largest_gap(_cap(rng, 20_000, 60.0, axis=(1.0, 0.0, 0.0)))
    assert radius == pytest.approx(120.0, abs=3.0) and centre[0] < -0.99
    assert largest_gap(np.zeros((0, 3)))[0] == 180.0 and coverage(np.zeros((0, 3))) == 0.0
