"""Divergence and stretch of the cable under random actions, per task and mode.

For every task and mode, runs ``--episodes`` episodes with uniformly random actions (the agent's exploration)
and counts:

* diverged episodes: the environment's own flag (``info["diverged"]``: MuJoCo's bad-acceleration warning,
  a reset seen in the C rollout, a non-finite or runaway state);
* MuJoCo warnings of every kind (``mjData.warning`` counters summed over the episode, and the text warnings
  MuJoCo issued, caught with ``mujoco.set_mju_user_warning``). MuJoCo resets a diverging simulation by itself
  (``auto-reset``), so a check of ``isfinite`` at the end alone would miss it;
* stretch: the largest relative deviation of an edge (node to node) length from its rest length, at every
  40 ms decision (``env.unwrapped.cable_nodes()`` after each ``env.step``, the issue's measure) and over every
  physics step of the episode (the C rollout's recorded states);
* non-finite states: physics steps whose recorded state has a NaN or an infinity;
* torn (vaulting): episodes ended because the TCP went farther from the support than the cable is long
  (``info["avoid"]["torn"]``), which the environment stops before the chain is dragged off its support.

    python benchmarks/chain_robustness.py [--model chain] [--episodes 1000] [--tasks tip-control hooking]
        [--modes single multi] [--damping S] [--integrator discrete] [--solver CG] [--json out.json] [--quick]

``--quick``: 1 episode per task and mode.

Prints one markdown row per task and mode, and a JSON summary with ``--json``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from dyndlo_vision.sim import CableParams, PhysicsOptions, paper_cable  # noqa: E402
from dyndlo_vision.tasks import make_env  # noqa: E402

TASKS = ("tip-control", "time-oscillation", "hooking", "vaulting")
_TEXT_WARNINGS: list[str] = []


def _count_warning(text: str) -> None:
    _TEXT_WARNINGS.append(text)


def task_cable(task: str, model: str, damping: float | None, quadratic: float | None = None) -> CableParams:
    """The task's paper cable (90 cm / 60 segments for vaulting, else 50 cm / 20) in the given model."""
    overrides: dict[str, Any] = {"model": model}
    if damping is not None:
        overrides["damping_s"] = damping
    if quadratic is not None:
        overrides["damping_quadratic_s2"] = quadratic
    return paper_cable(0.9 if task == "vaulting" else 0.5, **overrides)


def make_physics(args: argparse.Namespace) -> PhysicsOptions | None:
    fields = {k: v for k, v in (("integrator", args.integrator), ("solver", args.solver),
                                ("timestep_s", args.timestep)) if v is not None}
    return PhysicsOptions(**fields) if fields else None


class StretchProbe:
    """Wraps ``Scene.rollout`` to record the largest relative edge-length error of every state it returns."""

    def __init__(self, scene: Any) -> None:
        self.scene = scene
        self.rest = scene.config.cable.segment_length_m
        self.max_rel = 0.0
        self.non_finite = 0
        self._inner = scene.rollout
        scene.rollout = self._rollout

    def _rollout(self, controls: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        qpos, qvel, finite = self._inner(controls)
        self.non_finite += int(np.sum(~np.isfinite(qpos).all(axis=1) | ~np.isfinite(qvel).all(axis=1)))
        if finite:
            nodes = self.scene.nodes_from_qpos(qpos[:finite])
            edges = np.linalg.norm(np.diff(nodes, axis=1), axis=2)
            self.max_rel = max(self.max_rel, float(np.abs(edges / self.rest - 1.0).max()))
        return qpos, qvel, finite


def run(task: str, multi_step: bool, episodes: int, args: argparse.Namespace) -> dict[str, Any]:
    cable = task_cable(task, args.model, args.damping, args.quadratic)
    physics = make_physics(args)
    options: dict[str, Any] = {"cable": cable, "multi_step": multi_step}
    if physics is not None:
        options["physics"] = physics
    env = make_env(task, **options).unwrapped
    probe = StretchProbe(env.scene)
    rng = np.random.default_rng(args.seed)
    diverged, torn, with_warnings, warnings_total, text_before = 0, 0, 0, 0, len(_TEXT_WARNINGS)
    first_bad: list[int] = []
    decision_stretch = 0.0
    rest = cable.segment_length_m
    sim_s = 0.0
    start = time.perf_counter()
    cpu = time.thread_time()
    for ep in range(episodes):
        env.reset(seed=args.seed + ep)
        d = env.scene.data
        for i in range(len(d.warning)):
            d.warning[i].number = 0
        done = False
        info: dict[str, Any] = {}
        while not done:
            action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
            _, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
            nodes = env.unwrapped.cable_nodes()
            if np.isfinite(nodes).all():
                edges = np.linalg.norm(np.diff(nodes, axis=0), axis=1)
                decision_stretch = max(decision_stretch, float(np.abs(edges / rest - 1.0).max()))
            else:
                decision_stretch = math.inf
        sim_s += info["sim_time_s"]
        n_warn = int(sum(d.warning[i].number for i in range(len(d.warning))))
        warnings_total += n_warn
        bad = bool(info.get("diverged"))
        diverged += bad
        torn += bool(info.get("avoid", {}).get("torn", False))
        with_warnings += n_warn > 0
        if (bad or n_warn) and len(first_bad) < 10:
            first_bad.append(args.seed + ep)
    return {
        "task": task, "mode": "multi" if multi_step else "single", "episodes": episodes,
        "diverged": diverged, "torn": torn, "episodes_with_warnings": with_warnings,
        "warnings": warnings_total,
        "text_warnings": len(_TEXT_WARNINGS) - text_before, "bad_seeds": first_bad,
        "max_stretch_rel": probe.max_rel, "max_decision_stretch_rel": decision_stretch,
        "non_finite_steps": probe.non_finite, "sim_s": sim_s, "wall_s": time.perf_counter() - start,
        "cpu_s": time.thread_time() - cpu, "cable": repr(cable), "physics": repr(env.scene.config.physics),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", default="chain", choices=("chain", "rod"))
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    parser.add_argument("--modes", nargs="+", default=["single", "multi"], choices=("single", "multi"))
    parser.add_argument("--damping", type=float, default=None, help="cable damping_s (default: the model's)")
    parser.add_argument("--quadratic", type=float, default=None,
                        help="cable damping_quadratic_s2 (chain; default: the model's)")
    parser.add_argument("--integrator", default=None)
    parser.add_argument("--solver", default=None)
    parser.add_argument("--timestep", type=float, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", help="write the results here")
    parser.add_argument("--quick", action="store_true", help="1 episode per task and mode")
    args = parser.parse_args()
    if args.quick:
        args.episodes = 1
    mujoco.set_mju_user_warning(_count_warning)
    print(f"# {platform.machine()}, {os.cpu_count()} cpus; mujoco {mujoco.__version__}; "
          f"{' '.join(sys.argv[1:])}", flush=True)
    print("| model | task | mode | episodes | diverged | torn | episodes with warnings | warnings | "
          "text warnings | non-finite steps | max stretch at decisions | max stretch, every step | "
          "sim-s / CPU-s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|", flush=True)
    results = []
    for task in args.tasks:
        for mode in args.modes:
            r = run(task, mode == "multi", args.episodes, args)
            results.append(r)
            print(f"| {args.model} | {task} | {mode} | {r['episodes']} | {r['diverged']} | {r['torn']} | "
                  f"{r['episodes_with_warnings']} | {r['warnings']} | {r['text_warnings']} | "
                  f"{r['non_finite_steps']} | {r['max_decision_stretch_rel']:.2e} | "
                  f"{r['max_stretch_rel']:.2e} | "
                  f"{r['sim_s'] / r['cpu_s']:.1f} |", flush=True)
            if r["bad_seeds"]:
                print(f"<!-- {task} {mode}: first bad seeds {r['bad_seeds']} -->", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"argv": sys.argv[1:], "mujoco": mujoco.__version__, "results": results}, fh, indent=1)


if __name__ == "__main__":
    main()
