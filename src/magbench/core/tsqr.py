"""Linear least squares over rows given block by block (TSQR), in memory of one block.

A least-squares fit over every sample of a long recording builds a design matrix of the
samples' size, and LAPACK copies it again (``np.linalg.lstsq`` on 2 million rows of 4 columns:
64 MB of design and 80 MB of copies). The tall-skinny QR instead takes the QR factor ``R`` of
each block ``[A_i | b_i]`` stacked under the ``R`` so far (Demmel et al., "Communication-optimal
parallel and sequential QR and LU factorizations", 2012): with ``[A | b] = Q R``, ``Q`` of
orthonormal columns, ``||A x - b|| = ||R_A x - r_b||`` for every ``x``, so the small system
``R_A x = r_b`` has the same least-squares and minimum-norm solutions as the whole one. It is
backward stable like ``lstsq`` (no squared condition number, as the normal equations would
have), so the two agree to round-off.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

__all__ = ["lstsq_blocks"]


def lstsq_blocks(blocks: Iterable[tuple[np.ndarray, np.ndarray]]
                 ) -> tuple[np.ndarray, int]:
    """The least-squares solution of the rows ``(A_i, b_i)`` stacked, one block at a time.

    Parameters
    ----------
    blocks : iterable of (ndarray (m_i, p), ndarray (m_i,))
        The design rows and their right-hand sides, block by block (any ``m_i >= 0``).

    Returns
    -------
    x : ndarray, shape (p,)
        The minimum-norm least-squares solution, as ``np.linalg.lstsq(A, b)[0]`` gives for the
        whole ``A`` and ``b`` to round-off.
    rank : int
        The rank of ``A`` with ``np.linalg.lstsq``'s default cut-off for the whole ``A``
        (singular values below ``eps * max(m, p)`` times the largest are dropped).

    Raises
    ------
    ValueError
        If no block has a row.
    """
    R: np.ndarray | None = None
    rows = 0
    p = 0
    for A, b in blocks:
        A = np.asarray(A, dtype=float)
        if A.shape[0] == 0:
            continue
        p = A.shape[1]
        rows += A.shape[0]
        stacked = np.empty((A.shape[0] + (0 if R is None else R.shape[0]), p + 1))
        top = 0 if R is None else R.shape[0]
        if R is not None:
            stacked[:top] = R
        stacked[top:, :p] = A
        stacked[top:, p] = b
        del A, b                        # a block's rows not held while the next is made
        R = np.linalg.qr(stacked, mode="r")
    if R is None:
        raise ValueError("least squares over no rows")
    # lstsq on the small R with the whole design's cut-off, so that the rank is the same
    rcond = np.finfo(float).eps * max(rows, p)
    x, _, rank, _ = np.linalg.lstsq(R[:, :p], R[:, p], rcond=rcond)
    return x, int(rank)
