import os

# rollouts are many tiny matrix ops: one BLAS thread (DESIGN §7)
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")
