"""The feedback table: policies through the control loop on randomised cables, with success by stiffness and
length tercile.

Each row is one ``dyndlo-vision demo --randomize-cable --episodes N --quiet`` run in a subprocess, as a user
would type it (``--seed`` 100000 by default: the evaluation seeds no training used), with the row's policy,
observation and cable ranges; the table is read from the runs' ``metrics.json``. Terciles are those of the
cables the seeds draw (the same for every row of one range: the cable is drawn from the episode's seed).

    python benchmarks/feedback_table.py --out /tmp/fb [--task tip-control] [--ranges beyond,training]
        [--rows "single=tip-control-single-step:true;ms=tip-control-multi-step:true,tracked,frozen"]
        [--extra="--push 0.2,-0.002,0,0"] [--quick]

``--quick``: 1 episode, the first range, each row's first observation only (a check that it runs).

Writes ``OUT/<ranges>-<row>-<observation>/`` (the demo's outputs) and ``OUT/table.json``; prints the table
as Markdown.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np

DEFAULT_ROWS = {
    "tip-control": "single=tip-control-single-step:true;multi=tip-control-multi-step:true,tracked,frozen",
    "vaulting": "single=vaulting:true,tracked",
}


def parse_rows(text: str) -> list[tuple[str, str, list[str]]]:
    """``"name=policy:obs,obs;..."`` -> [(name, policy, [obs, ...]), ...]."""
    rows = []
    for part in filter(None, (p.strip() for p in text.split(";"))):
        name, _, rest = part.partition("=")
        policy, _, observations = rest.partition(":")
        if not (name and policy and observations):
            raise SystemExit(f"bad row {part!r}; expected NAME=POLICY:OBS[,OBS...]")
        rows.append((name, policy, observations.split(",")))
    return rows


def terciles(values: np.ndarray, ok: np.ndarray, cuts: np.ndarray) -> list[str]:
    """Successes/episodes below, between and above the two ``cuts``."""
    bins = (values < cuts[0], (values >= cuts[0]) & (values <= cuts[1]), values > cuts[1])
    return [f"{int(ok[b].sum())}/{int(b.sum())}" for b in bins]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--task", default="tip-control", choices=sorted(DEFAULT_ROWS))
    ap.add_argument("--ranges", default="beyond,training")
    ap.add_argument("--rows", default=None, help="NAME=POLICY:OBS[,OBS];... (default: the task's)")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--seed", type=int, default=100000)
    ap.add_argument("--extra", default="",
                    help="more demo options for every row, given as --extra='--push 0.2,-0.002,0,0'")
    ap.add_argument("--quick", action="store_true", help="1 episode, the first range, first observations")
    args = ap.parse_args()
    ranges_list = args.ranges.split(",")
    rows_spec = parse_rows(args.rows or DEFAULT_ROWS[args.task])
    if args.quick:
        args.episodes, ranges_list = 1, ranges_list[:1]
        rows_spec = [(name, policy, observations[:1]) for name, policy, observations in rows_spec]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table = {"machine": f"{platform.machine()} {platform.processor() or ''}".strip(), "task": args.task,
             "episodes": args.episodes, "seed": args.seed, "rows": []}
    for ranges in ranges_list:
        for name, policy, observations in rows_spec:
            for obs in observations:
                run = out / f"{ranges}-{name}-{obs}"
                cmd = [sys.executable, "-m", "dyndlo_vision", "demo", "--task", args.task, "--policy", policy,
                       "--observation", obs, "--randomize-cable", "--cable-ranges", ranges,
                       "--episodes", str(args.episodes), "--seed", str(args.seed), "--quiet",
                       "--out", str(run), *args.extra.split()]
                if not (run / "metrics.json").is_file():
                    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
                m = json.loads((run / "metrics.json").read_text())
                eps = m["episodes"]
                table["rows"].append({
                    "ranges": ranges, "row": name, "policy": policy, "observation": obs,
                    "command": " ".join(cmd[2:]).replace(str(run), "OUT"),
                    "successes": m["successes"], "episodes": len(eps), "success_ci95": m["success_ci95"],
                    "young_pa": [e["cable"]["young_pa"] for e in eps],
                    "length_m": [e["cable"]["length_m"] for e in eps],
                    "success": [bool(e["success"]) for e in eps],
                    "estimate_rmse_m_median": m["estimate_rmse_m_median"], "cycle_ms_p95": m["cycle_ms_p95"],
                })
    (out / "table.json").write_text(json.dumps(table, indent=1))
    for ranges in ranges_list:
        rows = [r for r in table["rows"] if r["ranges"] == ranges]
        young = np.array(rows[0]["young_pa"])
        length = np.array(rows[0]["length_m"])
        ce, cl = np.quantile(young, [1 / 3, 2 / 3]), np.quantile(length, [1 / 3, 2 / 3])
        print(f"\n{args.task}, --cable-ranges {ranges}, seeds {args.seed}-{args.seed + args.episodes - 1} "
              f"{args.extra}\n")
        print(f"| policy | observation | success | 95% CI | by E tercile (< {ce[0] / 1e6:.2f} / "
              f"{ce[0] / 1e6:.2f}-{ce[1] / 1e6:.2f} / > {ce[1] / 1e6:.2f} MPa) | by length tercile (< "
              f"{cl[0]:.3f} / {cl[0]:.3f}-{cl[1]:.3f} / > {cl[1]:.3f} m) | estimate RMSE median | p95 ms |")
        print("|---|---|---|---|---|---|---|---|")
        for r in rows:
            ok = np.array(r["success"])
            lo, hi = r["success_ci95"]
            print(f"| `{r['policy']}` | {r['observation']} | {r['successes']} | {lo:.2f}-{hi:.2f} | "
                  f"{', '.join(terciles(np.array(r['young_pa']), ok, ce))} | "
                  f"{', '.join(terciles(np.array(r['length_m']), ok, cl))} | "
                  f"{1e3 * r['estimate_rmse_m_median']:.1f} mm | {r['cycle_ms_p95']:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
