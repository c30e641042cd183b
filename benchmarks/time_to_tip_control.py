"""Wall time to 90 % tip-control success with the README's training command, by vectorised environment.

Runs ``dyndlo-vision train --task tip-control --algo sac --seed 1`` (the README's command; its evaluation
every 2 000 steps on 20 episodes) once per ``--vec-env`` given, one after the other, and watches the run's
``eval/evaluations.npz``: the wall time from the command's start to the end of the first evaluation at or
above 90 % success, and its step. The run is then stopped (SIGTERM: it checkpoints and exits). Runs that do
not get there within ``--timesteps`` report so.

    python benchmarks/time_to_tip_control.py [--quick] [--vec-env subproc batch] [--timesteps 16000]
        [--n-envs N]

The machine's load changes the wall time directly: say what else was running.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

THRESHOLD = 0.9


def run(vec_env: str, timesteps: int, eval_freq: int, eval_episodes: int, n_envs: int | None,
        out: Path, poll_s: float = 0.5) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "dyndlo_vision", "train", "--task", "tip-control", "--algo", "sac",
           "--seed", "1", "--timesteps", str(timesteps), "--eval-freq", str(eval_freq), "--eval-episodes",
           str(eval_episodes), "--vec-env", vec_env, "--out", str(out), "--quiet"]
    if n_envs is not None:
        cmd += ["--n-envs", str(n_envs)]
    evals = out / "eval" / "evaluations.npz"
    start = time.perf_counter()
    process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seen, curve = 0.0, []
    result: dict[str, Any] = {"vec_env": vec_env, "n_envs": n_envs, "command": " ".join(cmd[1:])}
    while True:
        ended = process.poll() is not None  # read the file once more after the run ends
        if not ended:
            time.sleep(poll_s)
        if not evals.is_file() or evals.stat().st_mtime == seen:
            if ended:
                break
            continue
        seen = evals.stat().st_mtime
        try:
            data = np.load(evals)
            rates = data["successes"].mean(axis=1)
            steps = data["timesteps"]
        except (OSError, KeyError, ValueError, EOFError):  # caught while being written: read it next time
            seen = 0.0
            continue
        curve = [(int(s), float(r)) for s, r in zip(steps, rates, strict=True)]
        if rates.size and rates[-1] >= THRESHOLD:
            result.update(reached=True, steps=int(steps[-1]), wall_s=round(time.perf_counter() - start, 1))
            if not ended:
                process.send_signal(signal.SIGTERM)
            break
        if ended:
            break
    output, _ = process.communicate()
    result.setdefault("reached", False)
    result.setdefault("wall_s_total", round(time.perf_counter() - start, 1))
    result["curve"] = curve
    if not result["reached"] and process.returncode not in (0, 130):
        result["error"] = output[-2000:]
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--vec-env", nargs="+", default=["subproc", "batch"])
    parser.add_argument("--timesteps", type=int, default=16000)
    parser.add_argument("--n-envs", type=int, default=None, help="default: the YAML's (2)")
    parser.add_argument("--quick", action="store_true", help="200 steps, 2 evaluations of 2 episodes")
    args = parser.parse_args()
    timesteps, eval_freq, eval_episodes = (200, 100, 2) if args.quick else (args.timesteps, 2000, 20)
    load = os.getloadavg()[0]
    print(f"# {platform.machine()}, {os.cpu_count()} cpus, load average {load:.1f} at the start")
    for kind in args.vec_env:
        with tempfile.TemporaryDirectory() as tmp:
            row = run(kind, timesteps, eval_freq, eval_episodes, args.n_envs, Path(tmp) / "run")
        print(json.dumps(row), flush=True)
        if "error" in row:
            sys.exit(f"the {kind} run failed")


if __name__ == "__main__":
    main()
