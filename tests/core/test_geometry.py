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


def test_direction_cells_are_equal_area():
    from magbench.core.geometry import DIRECTION_CELLS, direction_cells

    counts = np.bincount(direction_cells(fibonacci_sphere(100 * DIRECTION_CELLS)))
    assert counts.size == 14 * 28                          # 14 bands of z, 28 of longitude
    mean = 100 * DIRECTION_CELLS / counts.size
    assert 0.9 * mean <= counts.min() and counts.max() <= 1.1 * mean


def test_a_still_stretch_is_thinned_to_one_cell_and_an_even_sphere_is_not():
    from magbench.core.geometry import (
        CELL_CAP_FACTOR,
        CELL_CAP_MIN,
        direction_cells,
        thin_by_direction,
    )

    rng = np.random.default_rng(0)
    sphere = rng.permutation(fibonacci_sphere(2000))
    assert thin_by_direction(sphere).all()                    # nothing to thin
    still = np.array([0.3, 0.2, 0.9]) + 1e-4 * rng.standard_normal((2000, 3))
    keep = thin_by_direction(np.vstack([still, sphere]))
    same = direction_cells(sphere) == direction_cells(still[:1])[0]
    assert keep[2000:][~same].all()                           # other directions untouched
    cap = np.bincount(direction_cells(sphere)).max()
    assert CELL_CAP_MIN <= keep[:2000].sum() <= CELL_CAP_FACTOR * cap   # a cell of the still
    kept = np.flatnonzero(keep[:2000])
    assert kept[0] == 0 and kept[-1] > 1500                   # spread over the stretch


def test_distinct_rows_collapse_a_still_stretch_whatever_the_offset():
    from magbench.core.geometry import distinct_rows

    rng = np.random.default_rng(1)
    sphere = fibonacci_sphere(500) * 50.0 + [900.0, -300.0, 40.0]
    still = sphere[0] + 0.05 * rng.standard_normal((1500, 3))
    rows = distinct_rows(np.vstack([still, sphere]))
    assert np.sum(rows < 1500) <= 8 and np.sum(rows >= 1500) >= 400


@pytest.mark.parametrize(("z_range", "low", "high"), [((-1.0, 1.0), 65, 80),
                                                      ((-0.259, 0.259), 12, 16),
                                                      ((0.5, 1.0), 35, 55)])
def test_band_half_width_of_a_sphere_a_band_and_a_cap(z_range, low, high):
    from magbench.core.geometry import band_half_width

    assert low <= band_half_width(fibonacci_sphere(3000, z_range=z_range)) <= high
