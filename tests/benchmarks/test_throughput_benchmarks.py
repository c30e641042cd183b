"""The throughput benchmarks run in their quick mode and print what they promise (the figures themselves are
measured and recorded in docs/throughput.md, not asserted: timings are not tests)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def run(script: str, *args: str, timeout: float = 900) -> str:
    done = subprocess.run([sys.executable, str(BENCHMARKS / script), *args], capture_output=True, text=True,
                          timeout=timeout)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


@pytest.mark.slow
def test_env_throughput_quick_compares_the_vectorised_environments() -> None:
    out = run("env_throughput.py", "--quick")
    rows = [line for line in out.splitlines() if line.startswith("| ") and "steps/s" not in line]
    kinds = {(r.split("|")[1].strip(), r.split("|")[2].strip(), r.split("|")[3].strip()) for r in rows}
    for mode in ("single-step", "multi-step"):
        assert {(mode, "dummy", "1"), (mode, "subproc", "2"), (mode, "batch", "2")} <= kinds
    for r in rows:
        cells = [c.strip() for c in r.split("|")[1:-1]]
        assert float(cells[3]) > 0 and float(cells[4]) > 0
    one_core = json.loads(out.strip().splitlines()[-1])
    assert one_core["single_env_episodes_per_cpu_s"] > 0 and one_core["batched_episodes_per_cpu_s"] > 0


@pytest.mark.slow
def test_env_profile_quick_splits_a_decision_into_its_parts() -> None:
    out = run("env_profile.py", "--quick", "--n-envs", "2")
    rows = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    assert len(rows) == 4  # single and batched, single- and multi-step
    for row in rows:
        parts = sum(row[k] for k in ("physics", "plan", "references", "monitor", "rest"))
        assert row["physics"] > 0 and row["plan"] > 0 and row["monitor"] > 0
        assert parts == pytest.approx(row["total_profiled_s"], rel=0.02)


@pytest.mark.slow
def test_time_to_tip_control_quick_runs_the_training_command() -> None:
    out = run("time_to_tip_control.py", "--quick", "--vec-env", "batch")
    row = json.loads(out.strip().splitlines()[-1])
    assert row["vec_env"] == "batch" and "error" not in row
    assert [step for step, _ in row["curve"]] == [100, 200]  # both evaluations were seen


@pytest.mark.slow
def test_warp_backend_quick_reports_every_task_or_that_warp_is_absent() -> None:
    out = run("warp_backend.py", "--quick", timeout=3000)
    rows = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    if rows and "mujoco_warp" in rows[0]:
        assert "not installed" in rows[0]["mujoco_warp"]
        return
    from dyndlo_vision.tasks import TASKS

    assert [r["task"] for r in rows] == list(TASKS)
    assert all("put_model" in r for r in rows)
    # Every task loads, as built or with the sparse Jacobian, and its rollout is compared (or its failure
    # recorded).
    assert all("ok" in (r["put_model"], r.get("put_model_sparse_jacobian")) for r in rows)
    assert all("warp_nan_from_step" in r or "rollout" in r for r in rows)
