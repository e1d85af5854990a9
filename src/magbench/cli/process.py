"""Process-wide settings of a magbench command, made before NumPy is imported.

Two settings decide how fast NumPy-heavy calibration calls run, and neither can be made from
inside a library call:

- **One BLAS thread.** The work is many 3x3 and Kx4-Kx9 products, where BLAS threads only add
  start-up and spinning, and joblib already runs one process per core.
- **glibc's malloc keeps what it frees.** By default glibc serves every allocation above
  128 KiB (a (K, 9) array at K >= 2000) with a fresh ``mmap`` and hands it back on free, and
  trims the heap's free top above 128 KiB: each call then pays the kernel's page faults
  again for memory it just released. Measured for TWOSTEP at K = 10 000 (median of 40 calls,
  one process): 4.9 ms with glibc's defaults, 3.0 ms with these settings; at K = 3000 it is
  1.0 ms either way, so the default made the cost grow faster than K (slope 1.4 from 3000 to
  10 000 instead of 0.9). The price is a process that keeps its peak heap until it ends.

Each is a default: a value already in the environment is kept. The environment carries them to
the processes a command starts (sweep workers, the picture process); this process gets them
from ``mallopt`` (glibc only; elsewhere only the BLAS setting applies).
"""

from __future__ import annotations

import os
import sys

__all__ = ["PROCESS_ENV", "configure_process"]

#: Environment defaults of a magbench process and the processes it starts.
PROCESS_ENV = {
    "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
    # glibc's mallopt parameters as environment variables (read when a process starts):
    # allocations up to 32 MiB from the heap (glibc's largest), no trimming below 512 MiB
    "MALLOC_MMAP_THRESHOLD_": str(32 << 20), "MALLOC_TRIM_THRESHOLD_": str(512 << 20),
}

# glibc's <malloc.h> parameter numbers
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


def configure_process() -> bool:
    """Set :data:`PROCESS_ENV`'s defaults, and glibc's malloc thresholds of this process from
    the environment's values (module notes). Returns whether the malloc thresholds apply to
    this process (glibc found and accepted them)."""
    for key, value in PROCESS_ENV.items():
        os.environ.setdefault(key, value)
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt          # absent from musl and other C libraries
    except (OSError, AttributeError):
        return False
    try:
        mmap = int(os.environ["MALLOC_MMAP_THRESHOLD_"])
        trim = int(os.environ["MALLOC_TRIM_THRESHOLD_"])
    except ValueError:            # a value set by the user that glibc will not read either
        return False
    if not all(0 <= v < 2**31 for v in (mmap, trim)):
        return False              # mallopt takes a C int (the variables still reach children)
    # mallopt returns 1 on success (0: a value out of glibc's range, left as it was)
    applied = [mallopt(_M_MMAP_THRESHOLD, mmap), mallopt(_M_TRIM_THRESHOLD, trim)]
    return all(code == 1 for code in applied)
