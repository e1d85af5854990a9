import numpy as np
import pytest

from magbench.core.geometry import fibonacci_sphere
from magbench.sources.synthetic import Point, make_dataset, trial_seed_sequence


def test_fibonacci_sphere_is_unit_and_balanced():
    m = fibonacci_sphere(300)
    np.testing.assert_allclose(np.linalg.norm(m, axis=1), 1.0, atol=1e-12)
    # Evenly spread: the mean direction is near zero and z-levels are equally spaced (Alg. 8).
    assert np.linalg.norm(m.mean(axis=0)) < 1e-2
    np.testing.assert_allclose(np.diff(m[:, 2]), -2.0 / 300, atol=1e-12)


def test_fibonacci_sphere_radius():
    np.testing.assert_allclose(np.linalg.norm(fibonacci_sphere(10, radius=2.5), axis=1), 2.5)


def test_dataset_follows_the_model_and_ranges():
    point = Point(sigma=0.0, beta=0.1, gamma=0.3)
    for seed in range(20):
        d = make_dataset(np.random.default_rng(seed), point)
        np.testing.assert_allclose(d.y, d.m @ d.T.T + d.h, atol=1e-14)
        alpha = d.T.trace() / 3  # diag = alpha + E_ii, so the trace mean is within beta
        assert 0.8 - 0.1 <= alpha <= 1.2 + 0.1
        assert np.all(np.abs(d.h) <= 0.3)
        off = d.T - np.diag(np.diag(d.T))
        assert np.all(np.abs(off) <= 0.1)


def test_noise_has_the_requested_spread():
    d = make_dataset(np.random.default_rng(0), Point(K=20000, sigma=0.01))
    residual = d.y - (d.m @ d.T.T + d.h)
    assert abs(residual.std() - 0.01) < 3e-4


def test_trial_streams_are_keyed_not_ordered():
    p = Point()
    a = np.random.default_rng(trial_seed_sequence(7, p, 3)).random(5)
    b = np.random.default_rng(trial_seed_sequence(7, p, 3)).random(5)
    c = np.random.default_rng(trial_seed_sequence(7, p, 4)).random(5)
    d = np.random.default_rng(trial_seed_sequence(7, Point(gamma=0.5), 3)).random(5)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c) and not np.allclose(a, d)


def test_point_key_is_by_value():
    assert Point(gamma=0.05).key == Point().key
    assert Point(gamma=0.15).key != Point().key


@pytest.mark.parametrize("kwargs", [{"K": 0}, {"sigma": -1.0}, {"beta": -0.1},
                                    {"alpha_low": 1.3, "alpha_high": 1.2}])
def test_point_rejects_bad_values(kwargs):
    with pytest.raises(ValueError):
        Point(**kwargs)


def test_full_sphere_points_keep_their_streams():
    # The coverage fields must not change the key (and so the data) of full-sphere points.
    import zlib

    text = "K=300;sigma=0.005;beta=0.05;gamma=0.05;alpha=0.8,1.2"
    assert Point().key == zlib.crc32(text.encode())
    assert Point(cap_deg=90).key != Point().key != Point(band_deg=10).key


@pytest.mark.parametrize(("kwargs", "z_low", "z_high", "fraction"), [
    ({}, -1.0, 1.0, 1.0),
    ({"cap_deg": 90}, 0.0, 1.0, 0.5),
    ({"cap_deg": 60}, 0.5, 1.0, 0.25),
    ({"band_deg": 30}, -0.5, 0.5, 0.5),
])
def test_partial_coverage_directions(kwargs, z_low, z_high, fraction):
    p = Point(K=200, **kwargs)
    m = p.directions
    np.testing.assert_allclose(np.linalg.norm(m, axis=1), 1.0)
    assert z_low - 1e-12 <= m[:, 2].min() and m[:, 2].max() <= z_high + 1e-12
    # evenly spread over the zone: z levels equally spaced and spanning it
    np.testing.assert_allclose(np.diff(m[:, 2]), -(z_high - z_low) / 200, atol=1e-12)
    assert p.covered_fraction == pytest.approx(fraction)


def test_full_sphere_directions_are_algorithm_8():
    np.testing.assert_array_equal(Point(K=50).directions, fibonacci_sphere(50))
