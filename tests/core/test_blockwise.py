"""The helpers that see every sample of a long recording (issue 40): the same numbers as the
whole-array expressions they replace, and bounded memory.

The known answers were computed by the whole-array versions (before the block-wise rewrite) on
the samples of :func:`_samples`; the rewrite must give them to the last bit, with blocks small
enough that the block boundaries fall inside the samples.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from magbench.core import geometry, robust
from magbench.core.geometry import column_medians, distinct_rows, row_norms, sphere_fit
from magbench.core.robust import corrected_norms, norm_residuals, screen
from magbench.core.verdict import central_spread_of_norms, central_spread_pct, noise_p95_pct


def _samples(n: int = 5000, seed: int = 40) -> np.ndarray:
    """A turned sensor with hard and soft iron, noise, and a spike every 97 samples."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    y = u @ np.diag([55.0, 48.0, 51.0]) + [12.0, -7.0, 3.5] + rng.normal(scale=0.3, size=(n, 3))
    y[::97] *= 3.0
    return y


@pytest.fixture(params=[geometry.BLOCK_ROWS, 701], ids=["default-blocks", "small-blocks"])
def blocks(request, monkeypatch):
    monkeypatch.setattr(geometry, "BLOCK_ROWS", request.param)
    monkeypatch.setattr(robust, "BLOCK_ROWS", request.param)
    return request.param


def _same(value, known, blocks: int):
    """``value == known`` to the last bit, or to round-off when the samples span several
    blocks, which :func:`sphere_fit` solves by TSQR instead of one ``lstsq``."""
    if blocks >= 5000:
        return value == known
    return value == pytest.approx(known, rel=1e-12, abs=0.0)


def test_known_answers_of_the_whole_array_versions(blocks):
    y = _samples()
    c, r = sphere_fit(y)
    assert _same(c.tolist(), [16.237076096047375, -9.634658156767403, 4.523059111454031], blocks)
    assert _same(r, 53.82013777683104, blocks)
    s = screen(y)
    assert _same(s.centre.tolist(), [12.03290821836166, -7.059471539211055, 3.5012954141253583],
                 blocks)
    assert _same(s.radius, 51.456724496981856, blocks)
    assert (int(s.inliers.sum()), int(s.kept.sum())) == (4948, 5000)
    assert noise_p95_pct(y, 51.0) == 124.04654695852514
    assert _same(central_spread_pct(y - c), 6.150265911983223, blocks)
    distinct = distinct_rows(y)
    assert (distinct.size, int(distinct.sum())) == (1802, 2872121)


def test_helpers_equal_the_expressions_they_replace(blocks):
    y = _samples(3001, seed=7)
    centre = np.array([12.0, -7.0, 3.5])
    T = np.array([[55.0, 1.0, 0.5], [0.0, 48.0, 0.7], [0.2, 0.0, 51.0]])
    rows = np.random.default_rng(1).random(y.shape[0]) < 0.7
    assert np.array_equal(row_norms(y, centre), np.linalg.norm(y - centre, axis=1))
    assert np.array_equal(row_norms(y), np.linalg.norm(y, axis=1))
    assert np.array_equal(row_norms(y[1:], y[:-1]), np.linalg.norm(y[1:] - y[:-1], axis=1))
    assert np.array_equal(column_medians(y), np.median(y, axis=0))
    assert np.array_equal(geometry.direction_cells(y, centre=centre),
                          geometry.direction_cells(y - centre))
    assert sphere_fit(y, rows)[1] == sphere_fit(y[rows])[1]
    assert np.array_equal(sphere_fit(y, rows)[0], sphere_fit(y[rows])[0])
    whole = np.linalg.norm(np.linalg.solve(T, (y - centre).T), axis=0)
    assert np.array_equal(corrected_norms(T, centre, y), whole)
    assert np.array_equal(norm_residuals(T, centre, y), whole - 1.0)
    assert np.array_equal(corrected_norms(T, centre, y, rows),
                          np.linalg.norm(np.linalg.solve(T, (y[rows] - centre).T), axis=0))
    assert central_spread_of_norms(whole) == central_spread_pct(
        np.linalg.solve(T, (y - centre).T).T)


def _peak(call) -> int:
    """Peak bytes that NumPy and Python allocate during ``call()`` (tracemalloc; LAPACK's own
    work arrays are not counted)."""
    call()                                  # imports and caches outside the measurement
    tracemalloc.start()
    try:
        call()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_screen_and_noise_take_bounded_memory():
    # 200 000 samples (4.8 MB): the whole-array versions peaked at 6.1 and 3.3 times the
    # samples' bytes, the block-wise ones at 2.1 and 1.0 (the sphere fit's design matrix and
    # its least-squares copy; one axis's second differences and their median's copy).
    y = _samples(200_000)
    assert _peak(lambda: screen(y)) < 3.0 * y.nbytes
    assert _peak(lambda: noise_p95_pct(y, 51.0)) < 1.5 * y.nbytes


# --- core.blockwise: rows of whole-array NumPy results from a few rows (issue 40, attitude logs)


def _times(n: int, uniform: bool) -> np.ndarray:
    t = 0.125 * np.arange(n)                  # exact steps: numpy's uniform formula
    if not uniform:
        t = t + 0.02 * np.random.default_rng(5).random(n)       # jittered, still increasing
    return t


@pytest.mark.parametrize("uniform", [True, False], ids=["uniform", "jittered"])
@pytest.mark.parametrize("size", [1, 2, 7, 1000])
def test_gradient_rows_are_numpy_gradient_to_the_last_bit(uniform, size):
    from magbench.core.blockwise import gradient_rows, gradient_spacing, halo
    from magbench.core.quaternions import blocks as slices

    t = _times(1000, uniform)
    f = _samples(1000, seed=3)
    spacing = gradient_spacing(t)
    assert (spacing is not None) == uniform
    rows = np.concatenate([gradient_rows(t, f[halo(b, len(t))], b, spacing)
                           for b in slices(len(t), size)])
    assert np.array_equal(rows, np.gradient(f, t, axis=0))


def test_interp_rows_are_numpy_interp_to_the_last_bit():
    from magbench.core.blockwise import interp_rows
    from magbench.core.lag import shift
    from magbench.core.quaternions import blocks as slices

    t = _times(3000, uniform=False)
    f = _samples(3000, seed=4)
    f[100:103] = np.nan                                  # gaps stay gaps
    for lag in (-0.0731, 0.0, 0.05, 0.125 * 2999.5, 0.125 * 4000):
        whole = shift(t, f, -lag)
        parts = [interp_rows(t, f, t[b] + -lag) for b in slices(len(t), 257)]
        assert np.array_equal(np.concatenate(parts), whole, equal_nan=True)
    assert np.isnan(interp_rows(t, f, t[:10] - 10.0)).all()       # before the stream: NaN


def test_column_sums_and_mean_direction_rows_are_the_whole_arrays():
    from magbench.core.blockwise import column_sums, mean_direction_rows
    from magbench.core.direction import mean_direction

    x = _samples(5000, seed=6)
    parts = [x[i:i + 333] for i in range(0, len(x), 333)]
    assert np.array_equal(column_sums(parts), x.sum(axis=0))
    x[17] = np.nan
    x[40, 1] = np.nan
    parts = [x[i:i + 333] for i in range(0, len(x), 333)]
    assert np.array_equal(mean_direction_rows(iter(parts)), mean_direction(x))
    # known answer of the whole-array mean direction of these samples
    assert mean_direction_rows(iter(parts)).tolist() == pytest.approx(
        [0.83531816338546, -0.49375724123584125, 0.24175887294060763], abs=1e-15)
    with pytest.raises(ValueError, match="no rows"):
        column_sums([])


def test_affine_rows_by_chunks_are_the_whole_product_to_round_off():
    # Issue 40: (y - b) A^T made a chunk at a time; one chunk is the one product, bit for bit.
    from magbench.core.blockwise import affine_rows

    rng = np.random.default_rng(2)
    y = rng.normal(size=(3, 10_001)).T * 50.0
    A, b = rng.normal(size=(3, 3)), rng.normal(size=3)
    whole = (y - b) @ A.T
    assert np.array_equal(affine_rows(y, A, b, 10_001), whole)
    chunked = affine_rows(y, A, b, 1000)
    assert chunked.shape == whole.shape
    assert np.allclose(chunked, whole, rtol=1e-15, atol=1e-12)
