"""Do a distillation run's labels conflict where the student's observations agree, and does the clock fix it?

For each ``dyndlo-vision distill`` run given, takes the rounds' data (the observations as the student saw
them, the expert's labels, the episodes) and reports, with :func:`dyndlo_vision.learning.diagnostics.
label_conflict`, how far apart the labels of look-alike decisions from different episodes are:

- ``table II``: what a student without extra features reads;
- ``+ clock``: the same with the decision clock appended (the time since the episode began);
- ``+ shuffled clock``: the clock's values on the wrong decisions (what appending any one column changes);
- diagnostics no student may have, to find what the labels depend on: ``true state`` (the simulator's
  observation, without the tracker-noise model), ``+ expert's plan`` (the plan the expert follows in the
  episode, its first label, on every decision) and ``+ cable`` (the episode's cable factors: length, mass,
  Young's modulus, damping, drawn again from the seed as the run drew them).

With ``--fit-seeds``, it also fits fresh students (the run's network and epochs; one per seed, which sets the
initial weights and the held-out tenth of the episodes) on the same data with and without the clock, and
reports their validation MSE; ``--save DIR`` keeps each as ``DIR/<run>-<clock|table2>-s<seed>.zip`` with the
JSON ``policies.load`` reads, for ``benchmarks/feedback_table.py``. Students fitted on the same data differ
by up to 15 points of success through the loop, so compare several seeds. Rounds are selected with
``--rounds`` (default: all the run has).

    python benchmarks/label_conflict.py RUN [RUN ...] [--rounds 0,1] [--fit-seeds 1,2,3] [--save DIR]
        [--out F.json]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

import dyndlo_vision  # noqa: F401  (before mujoco)
from dyndlo_vision.learning.diagnostics import label_conflict, shuffled_control
from dyndlo_vision.learning.distill import Episodes, fit_student, make_distill_env, new_student, with_history
from dyndlo_vision.tasks.wrappers import DecisionClock, StudentFeaturesWrapper


def load_rounds(run: Path, rounds: list[int] | None) -> Episodes:
    """The run's round files (``round<r>.npz``), those of ``rounds`` or all, in one."""
    files = sorted(run.glob("round*.npz"), key=lambda p: int(p.stem[5:]))
    if rounds is not None:
        files = [run / f"round{r}.npz" for r in rounds]
    missing = [str(f) for f in files if not f.is_file()]
    if missing or not files:
        raise FileNotFoundError(f"no round data: {missing or run}")
    return Episodes.concatenate([Episodes.load(f) for f in files])


def episode_plans(data: Episodes) -> np.ndarray:
    """Each decision's episode's plan: the expert's first label (its ``start``), repeated over the episode."""
    starts = np.r_[0, np.flatnonzero(data.seeds[1:] != data.seeds[:-1]) + 1]
    return data.actions[np.repeat(starts, np.diff(np.r_[starts, len(data.seeds)]))]


def episode_cables(data: Episodes, config: dict[str, Any]) -> np.ndarray | None:
    """Each decision's cable factors (length, mass, Young's modulus, damping), None without random cables."""
    from dyndlo_vision.tasks.wrappers import cable_for_seed, cable_ranges_for

    ranges = config.get("cable_ranges")
    if ranges is None:
        return None
    task = config.get("task", "tip-control")
    env = make_distill_env(config.get("task_options", {}), None, None, task)
    n = env.unwrapped.task.cable
    env.close()
    factors = cable_ranges_for(task, ranges)
    rows = {}
    for seed in data.episode_seeds.tolist():
        c = cable_for_seed(n, factors, seed)
        rows[seed] = [c.length_m / n.length_m, c.mass_kg / n.mass_kg, c.young_pa / n.young_pa,
                      c.damping_s / n.damping_s]
    return np.array([rows[s] for s in data.seeds.tolist()])


def conflicts(data: Episodes, config: dict[str, Any]) -> dict[str, Any]:
    """Label conflict without and with the clock, with a shuffled clock, and the diagnostics."""
    clock = DecisionClock().stack(data.observations, data.seeds)[:, -1:]
    rows = [
        ("table II", data.observations),
        ("+ clock", np.c_[data.observations, clock]),
        ("+ shuffled clock", np.c_[data.observations, shuffled_control(clock)]),
        ("true state", data.true_observations),
        ("+ expert's plan", np.c_[data.observations, episode_plans(data)]),
    ]
    cables = episode_cables(data, config)
    if cables is not None:
        rows.append(("+ cable", np.c_[data.observations, np.log(cables)]))
    out = {}
    for name, obs in rows:
        result = label_conflict(obs, data.actions, data.seeds)
        out[name] = {k: getattr(result, k) for k in ("pairs", "neighbour_distance", "conflict",
                                                      "close_conflict")}
    return out


def fits(data: Episodes, config: dict[str, Any], seeds: list[int], save: Path | None,
         name: str) -> dict[str, Any]:
    """Validation MSE of fresh students fitted with and without the clock (the run's history, if any)."""
    import torch

    task = config.get("task", "tip-control")
    env = make_distill_env(config.get("task_options", {}), None, None, task)
    history = int(config.get("p_dlo_history", 0))
    out: dict[str, Any] = {}
    for clock in (False, True):
        key = "+ clock" if clock else "table II"
        out[key] = []
        for seed in seeds:
            torch.manual_seed(seed)
            student_env = StudentFeaturesWrapper(env, history, clock) if (history or clock) else env
            model = new_student(student_env, config.get("net_arch", (256, 256, 256)), seed)
            start = time.monotonic()
            losses = fit_student(model, with_history(data, history, clock),
                                 epochs=int(config.get("epochs", 300)), seed=seed)
            out[key].append({"seed": seed, **losses, "fit_s": round(time.monotonic() - start, 1)})
            if save is not None:
                stem = save / f"{name}-{'clock' if clock else 'table2'}-s{seed}"
                model.save(stem.with_suffix(".zip"))
                meta = {"task": task, "multi_step": True, "algo": "ppo", "env_options":
                        config.get("task_options", {}), "p_dlo_history": history, "decision_clock": clock}
                stem.with_suffix(".json").write_text(json.dumps(meta, indent=2))
    env.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("runs", nargs="+", type=Path, help="distill run folders")
    parser.add_argument("--rounds", help="comma-separated round indices (default: every round file)")
    parser.add_argument("--fit-seeds", help="comma-separated seeds: fit students with and without the clock")
    parser.add_argument("--save", type=Path, help="keep the fitted students in this folder")
    parser.add_argument("--out", type=Path, help="write the results as JSON")
    args = parser.parse_args()
    rounds = None if args.rounds is None else [int(r) for r in args.rounds.split(",")]
    import torch

    torch.set_num_threads(1)
    report: dict[str, Any] = {"machine": platform.platform(), "processor": platform.processor(), "runs": {}}
    for run in args.runs:
        data = load_rounds(run, rounds)
        config = json.loads((run / "config.json").read_text())
        entry: dict[str, Any] = {"decisions": int(len(data.actions)), "episodes": int(len(data.successes)),
                                 "conflict": conflicts(data, config)}
        print(f"{run} ({entry['episodes']} episodes, {entry['decisions']} decisions)")
        for name, c in entry["conflict"].items():
            print(f"  {name:18s} neighbour {c['neighbour_distance']:.3f}  conflict {c['conflict']:.4f}  "
                  f"closest half {c['close_conflict']:.4f}")
        if args.fit_seeds:
            seeds = [int(x) for x in args.fit_seeds.split(",")]
            if args.save:
                args.save.mkdir(parents=True, exist_ok=True)
            entry["fit"] = fits(data, config, seeds, args.save, run.name)
            for name, results in entry["fit"].items():
                val = [f["validation_mse"] for f in results]
                print(f"  fit {name:14s} validation MSE {' '.join(f'{v:.4f}' for v in val)} "
                      f"(median {np.median(val):.4f})")
        report["runs"][str(run)] = entry
    if args.out:
        args.out.write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
