"""Ali et al. PSO (Algorithm 5): fitness (45), determinism, stopping rules, recovery."""

from __future__ import annotations

import numpy as np
import pytest

import magbench
from magbench.core.metrics import accuracy_cost, trivial_cost
from magbench.methods.algorithms import ali
from magbench.methods.algorithms.magical import cost as magical_cost
from tests.conftest import dataset


def J74(cal, d) -> float:
    return accuracy_cost(cal.T, cal.h, d.T, d.h)[0]


def test_swarm_fitness_equals_the_per_particle_definition():
    d = dataset(seed=4)
    rng = np.random.default_rng(0)
    swarm = np.concatenate([np.zeros(3), np.eye(3).ravel()]) + rng.uniform(-0.5, 0.5, (30, 12))
    direct = np.array([ali.fitness_direct(d.y, *ali.split_particle(x)) for x in swarm])
    np.testing.assert_allclose(ali.SwarmFitness(d.y)(swarm), direct, rtol=1e-12)


def test_fitness_is_the_square_root_of_magical_cost_and_zero_at_the_truth():
    d = dataset(seed=4, sigma=0.0)
    x_true = np.concatenate([d.h, d.T.ravel()])[None]
    assert ali.SwarmFitness(d.y)(x_true)[0] < 1e-12
    noisy = dataset(seed=4)
    m = np.linalg.solve(noisy.T, (noisy.y - noisy.h).T).T
    assert ali.fitness_direct(noisy.y, noisy.T, noisy.h) == pytest.approx(
        np.sqrt(magical_cost(m)), rel=1e-12)


def test_a_singular_particle_gets_infinite_fitness_not_an_error():
    d = dataset(seed=4)
    swarm = np.tile(np.concatenate([np.zeros(3), np.eye(3).ravel()]), (3, 1))
    swarm[1, 3:6] = 0.0                                           # first row of T zero
    f = ali.SwarmFitness(d.y)(swarm)
    assert np.isinf(f[1]) and np.all(np.isfinite(f[[0, 2]]))


def test_same_seed_same_answer(nominal):
    a = magbench.calibrate(nominal.y, "ali", rng=np.random.default_rng(7))
    b = magbench.calibrate(nominal.y, "ali", rng=np.random.default_rng(7))
    np.testing.assert_array_equal(a.T, b.T)
    np.testing.assert_array_equal(a.h, b.h)
    assert a.n_iter == b.n_iter


def test_different_seeds_give_different_but_equally_good_answers(nominal):
    a = magbench.calibrate(nominal.y, "ali", rng=np.random.default_rng(7))
    b = magbench.calibrate(nominal.y, "ali", rng=np.random.default_rng(8))
    assert not np.array_equal(a.h, b.h)
    # Both sit at the minimum of (45), which MAG.I.C.AL. (same cost) also finds.
    ref = J74(magbench.calibrate(nominal.y, "magical"), nominal)
    assert J74(a, nominal) == pytest.approx(ref, rel=0.05)
    assert J74(b, nominal) == pytest.approx(ref, rel=0.05)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_noise_free_recovery_to_the_stated_bound(seed):
    # Measured on 100 noise-free nominal datasets: max J 1.1e-10; stated bound 1e-8.
    d = dataset(seed=seed, sigma=0.0)
    cal = magbench.calibrate(d.y, "ali", rng=np.random.default_rng(seed))
    assert cal.converged and "below tol" in cal.message
    assert J74(cal, d) < 1e-8


def test_noisy_data_end_by_stagnation_at_the_noise_floor(nominal):
    cal = magbench.calibrate(nominal.y, "ali", rng=np.random.default_rng(3))
    assert cal.converged and "stagnated" in cal.message
    assert J74(cal, nominal) < 0.01


def test_iteration_cap_gives_converged_false(nominal):
    cal = magbench.calibrate(nominal.y, "ali", rng=np.random.default_rng(3), max_iter=5)
    assert not cal.converged
    assert cal.n_iter == 5 and "iteration cap 5" in cal.message


def test_classic_coefficients_stall_at_the_scale_of_their_clamp(nominal):
    # w = 1, c1 = c2 = 2 never contracts below the clamp: an order of magnitude worse.
    constriction = J74(magbench.calibrate(nominal.y, "ali", rng=np.random.default_rng(3)),
                       nominal)
    classic = J74(magbench.calibrate(nominal.y, "ali", rng=np.random.default_rng(3),
                                     variant="classic"), nominal)
    assert classic > 3 * constriction


@pytest.mark.parametrize("seed", [0, 6])
def test_large_hard_iron_offset_is_found_from_the_data_centre(seed):
    d = dataset(seed=seed, gamma=1.0)
    cal = magbench.calibrate(d.y, "ali", rng=np.random.default_rng(seed))
    assert J74(cal, d) < 0.01 < 0.5 * trivial_cost(d.T, d.h)


def test_bound_keeps_the_answer_in_the_search_box(nominal):
    h0, r0 = ali.search_centre(nominal.y, "data")
    cal = ali.fit(nominal.y, rng=np.random.default_rng(0), bound=0.01)
    assert np.all(np.abs(cal.h - h0) <= 0.01 * r0 + 1e-15)
    assert np.all(np.abs(cal.T - r0 * np.eye(3)) <= 0.01 * r0 + 1e-15)


def test_unknown_variant_or_start_is_a_value_error(nominal):
    with pytest.raises(ValueError, match="variant must be one of"):
        magbench.calibrate(nominal.y, "ali", variant="nope")
    with pytest.raises(ValueError, match="start must be"):
        magbench.calibrate(nominal.y, "ali", start="nope")
