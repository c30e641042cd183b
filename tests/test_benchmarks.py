"""The benchmarks that stay are maintained: each runs in its --quick mode here, imports the package (never
another benchmark or the tests, no sys.path edits), and is listed in benchmarks/README.md."""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"

#: The maintained benchmarks: script -> the arguments of its quick run (with {tmp} for a scratch folder) and
#: a pattern its output must hold.
MAINTAINED: dict[str, tuple[list[str], str]] = {
    "feedback_table.py": (["--quick", "--out", "{tmp}/fb"],
                          r"\| `tip-control-multi-step` \| true \| [01] \|"),
    "joint_feasibility.py": (["--quick"], r'"feasible": \d+'),
    "clock_sync.py": (["--quick"], r'"estimate_below_true_offset_ms"'),
    "integrator_choice.py": (["--quick"], r"\| discrete \| 1 \| yes \|"),
    "task4_vs_geometric.py": (["time-oscillation-up", "--quick"], r'"residual_oscillation_m"'),
    "chain_robustness.py": (["--quick"], r"\| chain \| vaulting \| multi \| 1 \|"),
    "segmenter_engines.py": (["--quick"], r"\| `cable-segmenter-loop` \| 48x120x160 \| .* \| 0\.0\d{3} % \|"),
}
#: The perception benchmarks: maintained too; tests/tracking/test_perception_benchmarks.py checks their quick
#: runs.
PERCEPTION = {
    "track_videos.py", "tracking_accuracy.py", "tracking_speed.py", "loop_latency.py", "camera_latency.py",
    "loop_noise_model.py", "segmentation_generalisation.py",
}
#: Benchmarks other people own right now (the batched environment's throughput): listed in
#: benchmarks/README.md, not yet held to the rules above.
OWNED_ELSEWHERE = {"chain_speed.py", "sim_speed.py", "training_speed.py", "paper_model_speed.py"}
#: The batched environment's throughput: tests/benchmarks/test_throughput_benchmarks.py runs their quick
#: modes; the mutation runner: tests/test_mutation.py.
THROUGHPUT = {"env_throughput.py", "env_profile.py", "time_to_tip_control.py", "warp_backend.py"}
TOOLS = {"mutation.py"}


def test_every_benchmark_is_maintained_or_owned_elsewhere_and_listed() -> None:
    scripts = {p.name for p in BENCHMARKS.glob("*.py")}
    assert scripts - set(MAINTAINED) - PERCEPTION - OWNED_ELSEWHERE - THROUGHPUT - TOOLS == set(), (
        "a new benchmark needs --quick and a row here"
    )
    readme = (BENCHMARKS / "README.md").read_text()
    for name in scripts:
        assert f"`{name}`" in readme, f"benchmarks/README.md does not list {name}"


@pytest.mark.parametrize("name", sorted(set(MAINTAINED) | PERCEPTION))
def test_a_maintained_benchmark_imports_the_package_only(name: str) -> None:
    source = (BENCHMARKS / name).read_text()
    assert "sys.path" not in source
    siblings = {p.stem for p in BENCHMARKS.glob("*.py")}
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            modules = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            modules = [node.module or ""]
        else:
            continue
        for module in modules:
            top = module.split(".")[0]
            assert top not in siblings | {"tests", "conftest"}, f"{name} imports {module}"
    assert "--quick" in source


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(MAINTAINED))
def test_a_maintained_benchmark_runs_in_its_quick_mode(name: str, tmp_path: Path) -> None:
    args, expected = MAINTAINED[name]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / name), *(a.format(tmp=tmp_path) for a in args)],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert re.search(expected, done.stdout), done.stdout[-3000:]


@pytest.mark.slow
def test_the_segment_mode_times_the_whole_call_on_one_and_two_threads(tmp_path: Path) -> None:
    out = tmp_path / "segment.json"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / "segmenter_engines.py"), "--quick", "--segment", "--out", str(out)],
        capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    row = r"\| `cable-segmenter-loop` \| \d+\.\d\d ms \| \d+\.\d\d ms \|"
    assert re.search(row, done.stdout), done.stdout
    report = json.loads(out.read_text())
    assert set(report["segment_ms"]) == {"cable-segmenter-loop"}
    assert all(ms > 0 for ms in report["segment_ms"]["cable-segmenter-loop"].values())
    assert set(report["segment_ms"]["cable-segmenter-loop"]) == {"1 thread", "2 threads"}
