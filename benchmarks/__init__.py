"""The benchmark suite of latentune (run from the repository root: ``python -m benchmarks.NAME``;
shared pieces in :mod:`benchmarks.common`)."""
