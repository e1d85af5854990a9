"""TSQR (:func:`magbench.core.tsqr.lstsq_blocks`) gives ``np.linalg.lstsq``'s answer to
round-off, and the sphere fit that uses it finds an exact sphere's centre (issue 40)."""

from __future__ import annotations

import numpy as np
import pytest

from magbench.core import geometry
from magbench.core.geometry import fibonacci_sphere, sphere_fit
from magbench.core.tsqr import lstsq_blocks


def _cut(A: np.ndarray, b: np.ndarray, sizes: list[int]):
    """``(A, b)`` as consecutive blocks of the given row counts (then the rest)."""
    start = 0
    for size in sizes:
        yield A[start:start + size], b[start:start + size]
        start += size
    yield A[start:], b[start:]


@pytest.mark.parametrize("seed", range(6))
def test_random_designs_match_lstsq(seed):
    rng = np.random.default_rng(seed)
    m, p = int(rng.integers(20, 3000)), int(rng.integers(1, 9))
    # columns of very different scales, as [2 z, 1] of samples in counts would have
    A = rng.normal(size=(m, p)) * 10.0 ** rng.uniform(-3, 3, size=p)
    b = A @ rng.normal(size=p) + rng.normal(size=m)
    sizes = [int(s) for s in rng.integers(0, 400, size=6)]     # some blocks below p rows or empty
    x, rank = lstsq_blocks(_cut(A, b, sizes))
    expected, _, expected_rank, _ = np.linalg.lstsq(A, b, rcond=None)
    assert rank == expected_rank == p
    np.testing.assert_allclose(x, expected, rtol=1e-10, atol=0)


def test_a_rank_deficient_design_gives_lstsq_rank_and_minimum_norm_solution():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(500, 3))
    A = np.column_stack([A, A[:, 0] - 2 * A[:, 2]])        # the fourth column depends on two
    b = rng.normal(size=500)
    x, rank = lstsq_blocks(_cut(A, b, [7, 100, 2]))
    expected, _, expected_rank, _ = np.linalg.lstsq(A, b, rcond=None)
    assert rank == expected_rank == 3
    np.testing.assert_allclose(x, expected, rtol=1e-10, atol=1e-14)


def test_no_rows_is_refused():
    with pytest.raises(ValueError, match="least squares over no rows"):
        lstsq_blocks([(np.empty((0, 4)), np.empty(0))])


def test_sphere_fit_in_blocks_finds_an_exact_sphere(monkeypatch):
    monkeypatch.setattr(geometry, "BLOCK_ROWS", 997)
    centre = np.array([312.0, -148.5, 40.25])           # an offset of six field radii
    y = fibonacci_sphere(20_000, radius=55.0) + centre
    rows = np.arange(y.shape[0]) % 3 != 0
    for c, r in (sphere_fit(y), sphere_fit(y, rows)):
        np.testing.assert_allclose(c, centre, rtol=0, atol=1e-10)
        assert r == pytest.approx(55.0, rel=1e-12)


def test_sphere_fit_in_blocks_matches_the_whole_design(monkeypatch):
    rng = np.random.default_rng(40)
    u = rng.normal(size=(30_000, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    y = u @ np.diag([520.0, 480.0, 505.0]) + [120.0, -70.0, 35.0] + rng.normal(size=u.shape)
    rows = rng.random(y.shape[0]) < 0.8
    whole = sphere_fit(y, rows)                        # one block: lstsq on the design
    monkeypatch.setattr(geometry, "BLOCK_ROWS", 1000)
    blocks = sphere_fit(y, rows)
    np.testing.assert_allclose(blocks[0], whole[0], rtol=1e-10)
    assert blocks[1] == pytest.approx(whole[1], rel=1e-12)
    # a mask and a copy of the selected samples give the same blocks, so the same bits
    assert np.array_equal(blocks[0], sphere_fit(y[rows])[0]) and blocks[1] == sphere_fit(
        y[rows])[1]


def test_the_lag_fit_in_blocks_matches_the_whole_design(monkeypatch):
    from magbench.core.lag import _rate_fit

    rng = np.random.default_rng(5)
    u = rng.normal(size=(3000, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    rate = rng.normal(size=(3000, 3))
    A = np.eye(3) + 0.1 * rng.normal(size=(3, 3))
    observed = np.cross(u, rate @ A.T) + 0.01 * rng.normal(size=(3000, 3))
    rate[::97] = np.nan                                 # rows outside the rate stream
    whole = _rate_fit(u, rate, observed)                # one block: lstsq on the design
    monkeypatch.setattr(geometry, "BLOCK_ROWS", 256)
    blocks = _rate_fit(u, rate, observed)
    assert np.array_equal(np.isnan(blocks), np.isnan(whole)) and np.isnan(whole[::97]).all()
    np.testing.assert_allclose(blocks, whole, rtol=1e-10, atol=1e-12)
    rate[:] = np.nan                                    # no finite row: NaN, as the whole fit
    assert np.isnan(_rate_fit(u, rate, observed)).all()
