import os

from latentune.threads import one_thread_env

one_thread_env()  # rollouts are many tiny matrix operations: one BLAS thread
os.environ.setdefault("RAY_AUTH_MODE", "disabled")
