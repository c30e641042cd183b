"""Which lengths along a line run's correction vault which cables, and which gate that makes best.

For a ``dyndlo-vision distill --teacher-commit K --search-candidates line:N`` run, every cable the expert
corrected at decision K, and every other cable whose held-out gate probability reaches ``--min-probability``
(see ``dyndlo_vision.learning.correction_gate``), is run again by the run's expert up to decision K (same
teacher, smoothing and cable; the run's episodes are re-created exactly, which the expert's own plan-following
label at K checks: it vaults where the expert made no correction). There, each of ``--lengths`` along the
line is scored as the expert scores a candidate: re-plan with it and coast to the episode's end.

Then, for each length L and gate threshold t, the vaults a gated student would get on the run's cables if
it acted as the expert until K: a cable gated (held-out probability >= t) vaults if L vaults it; a cable not
gated vaults if the expert did not correct it. Cables below ``--min-probability`` are never gated for
thresholds at or above it, so the grid starts there.

Two counts. A candidate's score is 0 for a clean vault, exactly 1 for a vault with an avoid condition (in
practice the TCP over its 1.8 m/s), and above 1 for a miss (``CableSearchTeacher.score``). ``grid`` counts
clean vaults only, as the expert's search ranks them; ``grid_demo`` counts a vault as ``dyndlo-vision demo``'s
``success_rate`` does, with or without an avoid condition (the demo reports those beside it). A row
without the plan's own score ``"0"`` (rows written by an earlier draft of this script) counts a cable the
expert corrected as a plan miss in both.

    python benchmarks/correction_map.py RUN --lengths 0.1,0.2,0.3,0.4 --out map.jsonl --workers 2

``--out`` gets one JSON line per cable and is resumed (cables already in it are not run again); the table
goes to stdout and to ``OUT.summary.json``.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from dyndlo_vision import policies
from dyndlo_vision.learning.correction_gate import gate_examples, held_out_probabilities, line_direction
from dyndlo_vision.learning.distill import (
    PlanFollowingExpert,
    PolicyTeacher,
    ReplanSearch,
    make_distill_env,
    run_mixed_episode,
)

THRESHOLDS = (0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8)
GOOD = 0.03  # a score below this is a clean vault


def vaulted(score: float, with_avoided: bool) -> bool:
    """Whether a candidate's score is a vault: clean only, or also one with an avoid condition (score 1)."""
    return score < GOOD or (with_avoided and abs(score - 1.0) < 1e-9)


class _Mapped(Exception):
    """Raised by :class:`MapSearch` once it has scored the lengths: the rest of the episode is not needed."""


class MapSearch(ReplanSearch):
    """At the commitment, score the label and each length along the line; then stop the episode."""

    def __init__(self, candidates: str, lengths: list[float]) -> None:
        super().__init__(candidates=candidates)
        self.lengths = lengths
        self.scores: dict[str, float] = {}

    def search(self, env: Any, start: Any, seed: int) -> Any:
        snapshot = env.snapshot()
        origin = np.clip(np.asarray(start, dtype=np.float64), -1, 1)
        direction = self.line_direction(origin.size)
        self.scores = {"0": self._score(env, snapshot, origin)}
        for length in self.lengths:
            action = np.clip(origin + length * direction, -1, 1)
            self.scores[f"{length:+.2f}"] = self._score(env, snapshot, action)
        raise _Mapped


def map_cables(job: dict[str, Any]) -> list[dict[str, Any]]:
    """Score the lengths for each (seed, round) of ``job`` (one worker)."""
    import torch

    torch.set_num_threads(1)
    config = job["config"]
    env = make_distill_env(config.get("task_options") or {}, None, config.get("cable_ranges"), config["task"])
    teacher = PolicyTeacher(policies.load(config["teacher"]))
    expert = PlanFollowingExpert(env.unwrapped.spec_actions,
                                 speed_limit_m_s=config.get("expert_speed_limit_m_s"),
                                 smoothing=config.get("expert_smoothing", 0.0))
    search = MapSearch(config["search_candidates"], job["lengths"])
    out = []
    with open(job["out"], "a") as f:
        for seed, rnd in job["cables"]:
            start = time.monotonic()
            search.scores = {}
            expert_noise = config.get("expert_noise", 0.0) if rnd > 0 else 0.0
            try:
                run_mixed_episode(env, teacher, expert, seed, None, 1.0, np.random.default_rng([seed, rnd]),
                                  expert_noise=expert_noise, commit=search,
                                  commit_decision=config["teacher_commit_decision"])
            except _Mapped:
                pass
            row = {"seed": seed, "round": rnd, "young_pa": env.unwrapped.task.cable.young_pa,
                   "scores": search.scores, "wall_s": round(time.monotonic() - start, 1)}
            f.write(json.dumps(row) + "\n")
            f.flush()
            out.append(row)
    env.close()
    return out


def table(examples: dict[str, Any], held: np.ndarray, rows: dict[int, dict[str, Any]], lengths: list[float],
          min_probability: float, with_avoided: bool = False) -> dict[str, Any]:
    """Vaults of a gated expert per length and threshold (see the module's docstring); ``with_avoided``:
    count vaults with an avoid condition too, as the demo does."""
    corrected = examples["corrected"]
    seeds = examples["seeds"]

    def plan_vaults(seed: int, was_corrected: bool) -> bool:  # the plan's own label at K, not corrected
        scores = rows.get(int(seed), {}).get("scores", {})
        return vaulted(scores["0"], with_avoided) if "0" in scores else not was_corrected

    plan_ok = np.array([plan_vaults(s, c) for s, c in zip(seeds, corrected, strict=True)])
    plan = int(plan_ok.sum())
    result: dict[str, Any] = {"cables": int(len(seeds)), "plan_vaults": plan, "grid": []}
    for length in lengths:
        key = f"{length:+.2f}"
        # a perfect gate: every corrected cable gated, no other
        perfect = int((plan_ok & ~corrected).sum()) + sum(
            vaulted(rows[int(s)]["scores"][key], with_avoided) for s in seeds[corrected])
        for t in (t for t in THRESHOLDS if t >= min_probability):
            vaults = 0
            for s, ok, p in zip(seeds, plan_ok, held, strict=True):
                vaults += vaulted(rows[int(s)]["scores"][key], with_avoided) if p >= t else bool(ok)
            result["grid"].append({"length": length, "threshold": t, "vaults": int(vaults),
                                   "gated": int((held >= t).sum()), "perfect_gate_vaults": int(perfect)})
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", help="a distill run with --teacher-commit K --search-candidates line:N")
    parser.add_argument("--lengths", default="0.1,0.2,0.3,0.4", help="lengths along the line (signed)")
    parser.add_argument("--min-probability", type=float, default=0.15,
                        help="map uncorrected cables whose held-out gate probability reaches this")
    parser.add_argument("--l2", type=float, default=1.0, help="the gate classifier's L2 penalty")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--max-cables", type=int, default=None, help="map at most this many (a quick check)")
    parser.add_argument("--out", required=True, help="JSON lines, one per cable (resumed if it exists)")
    args = parser.parse_args(argv)
    lengths = [float(v) for v in args.lengths.split(",")]
    run = Path(args.run)
    examples = gate_examples(run)
    config = {**examples["config"]}
    line_direction(config.get("search_candidates", "episode"), 1)  # refuses a run that is not a line
    held = held_out_probabilities(examples, args.l2)
    per_cable = zip(examples["seeds"], examples["rounds"], examples["corrected"], held, strict=True)
    wanted = [(int(s), int(r)) for s, r, c, p in per_cable if c or p >= args.min_probability]
    out = Path(args.out)
    done = {}
    if out.exists():
        for line in out.read_text().splitlines():
            row = json.loads(line)
            if all(f"{v:+.2f}" in row["scores"] for v in lengths):
                done[row["seed"]] = row
    todo = [c for c in wanted if c[0] not in done][: args.max_cables]
    print(f"{len(wanted)} cables to map ({int(examples['corrected'].sum())} corrected), {len(todo)} left",
          file=sys.stderr)
    jobs = [{"config": config, "lengths": lengths, "out": str(out), "cables": todo[i::args.workers]}
            for i in range(max(1, args.workers))]
    jobs = [j for j in jobs if j["cables"]]
    if jobs:
        with multiprocessing.get_context("spawn").Pool(len(jobs)) as pool:
            for rows in pool.map(map_cables, jobs):
                done.update({r["seed"]: r for r in rows})
    mapped = {s: done[s] for s, _ in wanted if s in done}
    if len(mapped) < len(wanted):
        print(f"{len(wanted) - len(mapped)} cables not mapped yet: no table", file=sys.stderr)
        return 0
    # the re-created episodes must be the run's: the expert's own label vaults where it did not correct
    check = [vaulted(mapped[s]["scores"]["0"], False) == (not c)
             for s, c in zip(examples["seeds"], examples["corrected"], strict=True)
             if s in mapped and "0" in mapped[s]["scores"]]
    summary = table(examples, held, mapped, lengths, args.min_probability)
    demo = table(examples, held, mapped, lengths, args.min_probability, with_avoided=True)
    corrected_seeds = examples["seeds"][examples["corrected"]]
    by_length, by_length_demo = (
        {f"{v:+.2f}": int(sum(vaulted(mapped[int(s)]["scores"][f"{v:+.2f}"], with_avoided)
                              for s in corrected_seeds)) for v in lengths}
        for with_avoided in (False, True))
    summary.update({"plan_vaults_demo": demo["plan_vaults"], "grid_demo": demo["grid"],
                    "corrected_vaulted_by_length_demo": by_length_demo})
    summary.update({"command": "python " + " ".join([sys.argv[0], *(argv or sys.argv[1:])]),
                    "run": str(run), "mapped": len(mapped),
                    "episodes_recreated": f"{sum(check)}/{len(check)}",
                    "corrected_vaulted_by_length": by_length})
    Path(str(out) + ".summary.json").write_text(json.dumps(summary, indent=2))
    best = max(summary["grid"], key=lambda g: g["vaults"])
    best_demo = max(demo["grid"], key=lambda g: g["vaults"])
    for g, d in zip(summary["grid"], demo["grid"], strict=True):
        print(f"L={g['length']:+.2f} t={g['threshold']:.2f}: {g['vaults']}/{summary['cables']} clean, "
              f"{d['vaults']} as the demo counts (plan {summary['plan_vaults']} / {demo['plan_vaults']}, "
              f"gated {g['gated']}, perfect gate {g['perfect_gate_vaults']} / {d['perfect_gate_vaults']})")
    print(f"best: L={best['length']:+.2f} t={best['threshold']:.2f} ({best['vaults']} clean); as the demo "
          f"counts: L={best_demo['length']:+.2f} t={best_demo['threshold']:.2f} ({best_demo['vaults']}); "
          f"episodes re-created: {summary['episodes_recreated']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
