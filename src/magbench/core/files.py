"""Atomic file writes: a reader never sees a half-written result.

Every file magbench writes goes to a temporary name beside its destination and is renamed into
place (atomic on POSIX), so a killed run leaves either the old file or the new one.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["atomic_path", "file_sha256", "write_csv_atomic", "write_text_atomic"]


@contextlib.contextmanager
def atomic_path(path: Path | str) -> Iterator[Path]:
    """A temporary path to write; renamed onto ``path`` when the block ends without error."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".tmp-{os.getpid()}-{path.name}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_csv_atomic(frame: pd.DataFrame, path: Path | str) -> None:
    """Write ``frame`` as CSV (no index) to ``path`` atomically; ``.gz`` paths are compressed."""
    with atomic_path(path) as tmp:
        compression = "gzip" if str(path).endswith(".gz") else None
        frame.to_csv(tmp, index=False, compression=compression)


def write_text_atomic(text: str, path: Path | str) -> None:
    """Write ``text`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def file_sha256(path: Path | str) -> str:
    """Hex SHA-256 of a file's bytes (to check a part file before reusing it)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
