"""The machine a run is made on, as runs and benchmarks record it."""
from __future__ import annotations

import os
import platform
from pathlib import Path
from typing import Any


def machine() -> dict[str, Any]:
    """The CPU the runs are made on: model name, widest vector extension (MKL and OpenBLAS
    choose their kernels by it, so the last bits of linear algebra, and after a few batches a
    seeded run's trajectory, depend on it) and cores (``benchmarks.peers`` compares these
    dicts across runs: keep the keys)."""
    info: dict[str, str] = {}                  # the first CPU's fields
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            info.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    flags = set(info.get("flags", "").split())
    simd = next((f for f in ("avx512f", "avx2", "avx", "sse4_2") if f in flags), None)
    return {"cpu": info.get("model name") or platform.processor() or None, "simd": simd,
            "cores": os.cpu_count()}


def loadavg() -> list[float] | None:
    """The 1-, 5- and 15-minute load averages (None where the platform has none)."""
    try:
        return [round(v, 2) for v in os.getloadavg()]
    except OSError:
        return None
