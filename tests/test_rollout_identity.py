"""Rollouts are bit-identical to the golden digests of main's code before the rollout speed-up
(``tests/data/rollout_golden.json``, made by ``python -m benchmarks.rollout_identity --steps 500
--per-task 7`` on an export of commit 7f6b88a): the cost, mean velocity and height (float.hex),
fell, fall step and reason, the SHA-256 of every trace array and of every commanded torque, for
7 θ of each of A1 trot, A1 jump (convex MPC) and Solo12 trot (kino-dynamic MPC), two of them
falls. Long resumable runs store costs of the code before; a change that moves one bit of a
rollout makes them inconsistent and must fail here. Regenerate the file only for a deliberate
change of the numbers.

The bits depend on the libraries and the CPU's vector kernels too: in another environment than
the file's (see :func:`benchmarks.rollout_identity.environment`) the test skips, saying why.
Two AVX-512 machines gave different bits from the same code (an AMD EPYC of family 25 and the
machine of the first file), so the environment also names numpy's SIMD dispatch targets and
the BLAS kernel. The file was made again on the first with the code of 7f6b88a (its
``src`` from ``git archive``, plus the current ``latentune/machine.py``, which
``benchmarks.common`` imports and which computes no rollout). The current code gives the same
21 digests there.

Each environment has its own golden file, made the same way (the code of 7f6b88a) and checked
the same (the current code gives its 21 digests): ``rollout_golden.json`` on the AVX-512 EPYC
with OpenBLAS's SkylakeX kernels, ``rollout_golden_avx2.json`` on an AVX2 EPYC of family 25
(numpy's X86_V3 dispatch, OpenBLAS's Haswell kernels). The test takes the file of the
environment it runs in.
"""
from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("crocoddyl")

from benchmarks import rollout_identity as ri  # noqa: E402

GOLDEN = sorted((Path(__file__).resolve().parent / "data").glob("rollout_golden*.json"))


@pytest.fixture(scope="module")
def golden() -> dict:
    """The golden file of this environment; the test skips, saying why, where none is."""
    files = [json.loads(f.read_text()) for f in GOLDEN]
    env = ri.environment()
    for data in files:
        if env == data["environment"]:
            return data
    hint = ""
    for data in files:
        if {k: v for k, v in env.items() if k != "blas_kernel"} == \
                {k: v for k, v in data["environment"].items() if k != "blas_kernel"}:
            hint = (f"; only the BLAS kernel differs: OPENBLAS_CORETYPE="
                    f"{data['environment']['blas_kernel']} selects a golden one")
    pytest.skip(f"golden digests come from other environments: "
                f"{[d['environment'] for d in files]} (here: {env}){hint}")


def test_every_environment_has_its_golden_file_once():
    """Two golden files of one environment would make the choice above arbitrary."""
    envs = [json.dumps(json.loads(f.read_text())["environment"], sort_keys=True) for f in GOLDEN]
    assert len(GOLDEN) >= 2 and len(set(envs)) == len(envs)


@pytest.mark.parametrize("task", ["a1:trot", "a1:jump", "solo12:trot"])
def test_rollouts_are_bit_identical_to_main(golden, task):
    robot, gait = task.split(":")
    want = [r for r in golden["rows"] if (r["robot"], r["gait"]) == (robot, gait)]
    assert len(want) == golden["per_task"]
    got = ri.run([(robot, gait)], golden["steps"], golden["per_task"])
    assert [r["theta"] for r in got] == [r["theta"] for r in want]
    for g, w in zip(got, want):
        assert g["digest"] == w["digest"], (task, g["theta_index"])


def test_the_golden_set_covers_falls_and_full_runs(golden):
    """Both branches of the rollout loop are checked: runs to the horizon and falls."""
    fell = {(r["robot"], r["gait"]) for r in golden["rows"] if r["digest"]["fell"]}
    assert {("a1", "jump"), ("solo12", "trot")} <= fell
    assert all(any(not r["digest"]["fell"] for r in golden["rows"]
                   if (r["robot"], r["gait"]) == t) for t in fell)


def test_a_changed_bit_is_caught(golden):
    """The comparison sees one ulp: the digest of a rollout differs from a perturbed copy."""
    row = golden["rows"][0]
    other = json.loads(json.dumps(golden))
    cost = float.fromhex(row["digest"]["cost"])
    other["rows"][0]["digest"]["cost"] = (cost + cost * 2.0 ** -52).hex()
    assert ri.compare(golden, other) == [
        f"('{row['robot']}', '{row['gait']}', 0): cost differ"]
