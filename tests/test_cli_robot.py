"""The person at the robot through the CLI: asks by two askers, a mistyped result amended, a
suggestion released, status by phase name, the θ to deploy, and --strategy's refusals."""
from __future__ import annotations

import json

import yaml


def test_a_person_at_the_robot(tmp_path, run_cli, error_line):
    space = tmp_path / "space.yaml"
    space.write_text(yaml.safe_dump({"names": ["a", "b", "c"], "low": [0, 0, 0],
                                     "high": [1, 1, 1], "manual": [0.5, 0.5, 0.5]}))
    d = tmp_path / "robot"
    code, out, err = run_cli("ask", d, "--space", space, "--asker", "alice", "--json")
    assert code == 0, err
    (a,) = json.loads(out)
    assert a["asker"] == "alice" and a["phase_name"] == "phase 1"
    assert json.loads((d / "suggestions" / f"{a['id']}.json").read_text()).keys() == {"a", "b", "c"}
    code, out, err = run_cli("ask", d, "--asker", "bob", "--json")
    (b,) = json.loads(out)
    assert b["id"] != a["id"] and b["theta"] != a["theta"]          # another θ for bob
    assert run_cli("tell", d, a["id"], "--cost", "-3")[0] == 0       # a typo ...
    code, out, _ = run_cli("tell", d, a["id"], "--cost", "3", "--amend")
    assert code == 0 and out.startswith(f"amended {a['id']}")      # ... corrected
    assert not (d / "suggestions" / f"{a['id']}.json").exists()
    code, out, _ = run_cli("release", d, b["id"])
    assert code == 0 and "again" in out
    code, out, _ = run_cli("status", d, "--json")
    s = json.loads(out)
    assert s["phases"]["phase 1"]["n"] == 1 and s["amended"] == 1
    assert s["best"]["cost"] == 3.0 and s["best"]["trial"] == a["id"]
    code, out, _ = run_cli("best", d, "--out", tmp_path / "deploy.json")
    assert code == 0 and json.loads((tmp_path / "deploy.json").read_text()) == \
        {k: v for k, v in a["params"].items()}
    # a conflicting option on a later ask is refused, naming the stored one
    assert "turbo" in error_line(*run_cli("ask", d, "--method", "cma")[::2])


def test_strategy_flag_is_checked(tmp_path, run_cli, error_line):
    line = error_line(*run_cli("phase3", "--robot", "a1", "--task", "trot", "--out", tmp_path,
                               "--strategy", "transfer", "--handover")[::2])
    assert "--handover is an option of --strategy plain" in line
    assert "invalid choice" in error_line(*run_cli("phase3", "--robot", "a1", "--out", tmp_path,
                                                   "--strategy", "latent")[::2])
