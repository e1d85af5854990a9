"""The one seeding helper: every random number comes from a Generator keyed by names.

A stream is ``SeedSequence(base seed, spawn_key=keys)``. Keys are integers (a point's value
hash, a trial index) or strings (a method, a recording), strings hashed with CRC-32 so that a
stream depends on what it is for, never on the order in which work runs or on the workers.
"""

from __future__ import annotations

import zlib

import numpy as np

__all__ = ["rng", "seed_sequence", "stream_key"]


def stream_key(key: int | str) -> int:
    """An integer spawn key: integers as they are, strings by their CRC-32."""
    if isinstance(key, str):
        return zlib.crc32(key.encode())
    if isinstance(key, bool) or not isinstance(key, int | np.integer) or key < 0:
        raise ValueError(f"a stream key is a non-negative integer or a string, got {key!r}")
    return int(key)


def seed_sequence(seed: int, *keys: int | str) -> np.random.SeedSequence:
    """``SeedSequence(seed, spawn_key=keys)`` with string keys hashed (see module notes)."""
    return np.random.SeedSequence(int(seed), spawn_key=tuple(stream_key(k) for k in keys))


def rng(seed: int, *keys: int | str) -> np.random.Generator:
    """The Generator of the stream ``keys`` under the base ``seed``."""
    return np.random.default_rng(seed_sequence(seed, *keys))
