"""``python -m magbench sweep=gamma``: see :mod:`magbench.cli`."""

import os

# One BLAS thread per process: the work is many 3x3 and Kx4 products, where threads only add
# overhead, and joblib runs one process per core. Set before NumPy is first imported.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from magbench.cli import main  # noqa: E402

raise SystemExit(main())
