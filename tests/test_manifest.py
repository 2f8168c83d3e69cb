"""The run manifest's own methods (:class:`latentune.pipeline.manifest.Manifest`)."""
from __future__ import annotations

import numpy as np

from latentune.pipeline.manifest import Manifest
from latentune.pipeline.rundir import RunDir


def test_would_change_is_a_dry_run_of_update(tmp_path):
    """``Manifest.would_change(**kw)`` says whether ``update(**kw)`` would change the stored
    configuration, comparing what update would store with what is stored as JSON (NumPy values
    as numbers, key order ignored), and writes nothing: an ask uses it to copy the run store
    only when it records something."""
    m = Manifest(RunDir(tmp_path / "run"))
    assert m.would_change(seed=1) and not m.run.exists      # no store: nothing was created
    assert not m.would_change()
    m.update(seed=1, phase1={"method": "turbo", "batch_size": 4, "budget": 20})
    assert not m.would_change(seed=np.int64(1))
    assert not m.would_change(phase1={"budget": np.int64(20), "batch_size": 4, "method": "turbo"})
    assert m.would_change(phase1={"method": "turbo", "batch_size": 4, "budget": 21})
    assert m.would_change(phase1={"method": "turbo", "batch_size": 4})
    assert m.would_change(asktell={"phase": 1})
    assert m.config() == {"seed": 1, "phase1": {"method": "turbo", "batch_size": 4, "budget": 20}}
