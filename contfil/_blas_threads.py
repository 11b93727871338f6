"""Single-threaded BLAS for command-line runs.

The dense matrices of contfil's models are small (order 10^2); threaded BLAS
only adds contention on them (measured 30x slower LU solves on a loaded
2-core machine, docs/performance.md). Takes effect only if imported before
numpy; an explicit setting in the environment wins.
"""

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
