"""The smoke part of the mutation testing (``benchmarks/mutation.py --quick``, docs/mutation-testing.md).

mutmut plants one small bug at a time in the re-planner (``trajectory/replanner.py``: the arms' commanded
positions and velocities) and runs its tests against each: every mutant must make a test fail, or be listed
as equivalent in ``benchmarks/mutation_survivors.toml``. A change that weakens those tests, or a new rule in
the re-planner that no test checks, fails here. The full run (every module that decides outcomes) is the
script without ``--quick``; it takes hours, so CI runs this part only.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_every_replanner_mutant_is_killed_or_equivalent(tmp_path: Path) -> None:
    out = tmp_path / "quick.json"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "mutation.py"), "--quick", "--strict",
           "--workdir", str(tmp_path / "work"), "--json", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1200, check=False)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    total = json.loads(out.read_text())["groups"]["quick"]["total"]
    assert total["mutants"] >= 90, total  # the whole module was mutated
    assert total["no_tests"] == 0 and total["harmless"] == 0, total
    assert total["killed"] + total["timeout"] + total["equivalent"] == total["mutants"], total
