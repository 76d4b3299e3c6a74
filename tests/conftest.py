import os

# Simulation kernels are single-threaded by design; oversubscribed BLAS threads on a
# 2-core machine are 10-100x slower (docs/performance.md).
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
