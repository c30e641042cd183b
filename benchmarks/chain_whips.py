"""Statistics of whips: chain against rod and against fine-step references (issue 15, step 2).

Whip motion is chaotic, so single trajectories are not compared; distributions over seeds are. Every
configuration follows the same TCP plans in the tip-control scene (50 cm cable, TCP at (0.45, 0, 0.6)):
random tip-control single-step actions, their time axis stretched where needed so the TCP's peak speed is at
most ``--vmax`` (the paper's v_max, 1.8 m/s: the regime a trained policy uses). The TCP then holds still for
``--hold`` seconds. From the tip, sampled every 1 ms (whatever the timestep):

* peak tip speed during the motion and the 0.5 s after it (finite differences at 1 ms);
* free swing after that (TCP at rest): angular frequency (zero crossings of the tip's horizontal offset from
  the TCP, along its main direction) and decay rate sigma (1/s, amplitude ~ exp(-sigma t), from the largest
  offset over the first and over the last full period of the window).

    python benchmarks/chain_whips.py --seeds 40 --config NAME:MODEL:INTEGRATOR:DT:DAMPING[:QUAD] ...
        [--ref NAME] [--json out.json]

Per configuration: median and 10-90 % range of each statistic over the seeds, and per-seed differences from
the reference configuration (median of the absolute relative differences). Default configurations: the
chain (the package's defaults), the chain at 0.1 ms (same damping), the chain at 0.1 ms with the rod's
damping (0.002 s, a nearly undamped reference), the rod (package defaults) and the rod at 0.125 ms.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from dataclasses import dataclass
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from dyndlo_vision.sim import CableParams, PhysicsOptions, Scene  # noqa: E402
from dyndlo_vision.tasks import TipControl  # noqa: E402
from dyndlo_vision.trajectory import BSplineTrajectory  # noqa: E402

SAMPLE_S = 0.001


@dataclass(frozen=True)
class Config:
    name: str
    cable: CableParams
    physics: PhysicsOptions

    @classmethod
    def parse(cls, text: str) -> Config:
        parts = text.split(":")
        if len(parts) not in (4, 5, 6):
            raise SystemExit(f"--config {text!r}: expected NAME:MODEL:INTEGRATOR:DT[:DAMPING[:QUAD]]")
        name, model, integrator, dt = parts[:4]
        cable_kw: dict[str, Any] = {"model": model}
        if len(parts) > 4 and parts[4]:
            cable_kw["damping_s"] = float(parts[4])
        if len(parts) > 5:
            cable_kw["damping_quadratic_s2"] = float(parts[5])
        return cls(name, CableParams(**cable_kw), PhysicsOptions(integrator=integrator, timestep_s=float(dt)))


def default_configs() -> list[Config]:
    chain = CableParams(model="chain")
    rod = CableParams()
    return [
        Config("chain", chain, PhysicsOptions()),
        Config("chain 0.1 ms", chain, PhysicsOptions(timestep_s=0.0001)),
        Config("chain 0.1 ms, 0.002 s", CableParams(model="chain", damping_s=0.002, damping_quadratic_s2=0.0),
               PhysicsOptions(timestep_s=0.0001)),
        Config("rod", rod, PhysicsOptions()),
        Config("rod 0.125 ms", rod, PhysicsOptions(timestep_s=0.000125)),
    ]


def plans(seeds: int, vmax: float | None) -> list[BSplineTrajectory]:
    """Random tip-control single-step plans, slowed down to a peak TCP speed of at most ``vmax``."""
    task = TipControl()
    spec = task.action_spec()
    home = np.asarray(task.scene_config().grippers_m[0], dtype=float)
    out = []
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        points, times = spec.decode(rng.uniform(-1, 1, spec.size), home, 0.0, None)
        plan = BSplineTrajectory(points, times)
        if vmax is not None and plan.max_speed() > vmax:
            plan = BSplineTrajectory(points, times * plan.max_speed() / vmax)
        out.append(plan)
    return out


def simulate(scene: Scene, plan: BSplineTrajectory, hold_s: float) -> tuple[np.ndarray, np.ndarray, bool]:
    """Tip and TCP positions every ``SAMPLE_S`` from t = 0 to the plan's end + ``hold_s``, and stability."""
    scene.reset()
    dt = scene.timestep
    every = max(1, int(round(SAMPLE_S / dt)))
    total = int(round((plan.t_end + hold_s) / dt))
    tips, tcps = [scene.cable_nodes()[-1]], [scene.tcp_positions()[0]]
    chunk = every * 500
    ok = True
    for k0 in range(0, total, chunk):
        t = dt * np.arange(k0, min(total, k0 + chunk))
        p, v = plan.position(t), plan.velocity(t)
        qpos, _, finite = scene.rollout(scene.tcp_controls(p[:, None], v[:, None]))
        if finite < len(t):
            ok = False
            break
        rows = qpos[every - 1::every]
        tips.append(scene.nodes_from_qpos(rows)[:, -1])
        tcps.append(scene.tcp_from_state(rows, np.zeros((len(rows), scene.model.nv)))[0][:, 0])
    return np.vstack([np.atleast_2d(x) for x in tips]), np.vstack([np.atleast_2d(x) for x in tcps]), ok


def whip_statistics(tips: np.ndarray, tcps: np.ndarray, t_end: float) -> dict[str, float]:
    """Peak tip speed up to ``t_end + 0.5`` s; frequency and decay of the free swing after that."""
    t = SAMPLE_S * np.arange(len(tips))
    speed = np.linalg.norm(np.gradient(tips, SAMPLE_S, axis=0), axis=1)
    moving = t <= t_end + 0.5
    free = ~moving
    offset = (tips - tcps)[free, :2]
    offset = offset - offset.mean(axis=0)
    _, _, vt = np.linalg.svd(offset, full_matrices=False)
    x = offset @ vt[0]
    tf = t[free]
    idx = np.flatnonzero(np.signbit(x[:-1]) != np.signbit(x[1:]))
    out = {"peak_tip_speed": float(speed[moving].max()), "omega": math.nan, "decay": math.nan,
           "swing_amplitude": float(np.abs(x).max())}
    if len(idx) >= 3:
        crossings = tf[idx] + SAMPLE_S * x[idx] / (x[idx] - x[idx + 1])
        omega = float(math.pi / np.median(np.diff(crossings)))
        out["omega"] = omega
        # Decay: swing amplitude (largest |x|) over the first and the last full period of the window.
        period = 2 * math.pi / omega
        first = tf < tf[0] + period
        last = tf > tf[-1] - period
        if tf[-1] - tf[0] > 2 * period:
            a0, a1 = np.abs(x[first]).max(), np.abs(x[last]).max()
            span = float(np.mean(tf[last]) - np.mean(tf[first]))
            out["decay"] = float(math.log(a0 / a1) / span)
    return out


def summarise(values: list[float]) -> str:
    v = np.array([x for x in values if np.isfinite(x)])
    if v.size == 0:
        return "-"
    p10, p50, p90 = np.percentile(v, [10, 50, 90])
    return f"{p50:.3g} ({p10:.3g}-{p90:.3g})"


def paired_abs(values: list[float], ref: list[float]) -> str:
    """Median signed and absolute difference, paired by plan (for statistics near zero)."""
    a, b = np.array(values), np.array(ref)
    ok = np.isfinite(a) & np.isfinite(b)
    if not ok.any():
        return "-"
    diff = a[ok] - b[ok]
    return f"{np.median(diff):+.3g} / {np.median(np.abs(diff)):.3g}"


def paired(values: list[float], ref: list[float]) -> str:
    a, b = np.array(values), np.array(ref)
    ok = np.isfinite(a) & np.isfinite(b) & (b != 0)
    if not ok.any():
        return "-"
    rel = (a[ok] - b[ok]) / np.abs(b[ok])
    return f"{np.median(rel) * 100:+.1f} % / {np.median(np.abs(rel)) * 100:.1f} %"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--vmax", type=float, default=1.8, help="peak TCP speed cap (0: none)")
    parser.add_argument("--hold", type=float, default=4.0, help="seconds the TCP holds still after the plan")
    parser.add_argument("--config", action="append", help="NAME:MODEL:INTEGRATOR:DT[:DAMPING[:QUAD]]")
    parser.add_argument("--ref", help="name of the reference configuration (default: the second)")
    parser.add_argument("--json")
    args = parser.parse_args()
    mujoco.set_mju_user_warning(lambda text: None)
    configs = [Config.parse(c) for c in args.config] if args.config else default_configs()
    ref_name = args.ref or configs[min(1, len(configs) - 1)].name
    print(f"# {platform.machine()}, {os.cpu_count()} cpus; mujoco {mujoco.__version__}; "
          f"{' '.join(sys.argv[1:])}")
    trajectories = plans(args.seeds, args.vmax or None)
    task = TipControl()
    results: dict[str, dict[str, Any]] = {}
    for cfg in configs:
        task.cable, task.physics = cfg.cable, cfg.physics
        scene = Scene(task.scene_config())
        stats: dict[str, list[float]] = {key: [] for key in ("peak_tip_speed", "omega", "decay",
                                                             "swing_amplitude")}
        diverged = 0
        cpu = time.thread_time()
        for plan in trajectories:
            tips, tcps, ok = simulate(scene, plan, args.hold)
            if not ok:
                diverged += 1
                for key in stats:
                    stats[key].append(math.nan)
                continue
            for key, value in whip_statistics(tips, tcps, plan.t_end).items():
                stats[key].append(value)
        results[cfg.name] = {"stats": stats, "diverged": diverged, "cpu_s": time.thread_time() - cpu,
                             "cable": repr(cfg.cable), "physics": repr(cfg.physics)}
        print(f"# {cfg.name}: {cfg.cable} {cfg.physics}: {diverged} diverged, "
              f"{results[cfg.name]['cpu_s']:.0f} CPU-s", flush=True)
    ref = results[ref_name]["stats"]
    print(f"\nMedian (10-90 %) over {args.seeds} plans; vs '{ref_name}': median signed / median absolute "
          "difference, paired by plan (relative for speed and omega, in 1/s for the decay).\n")
    print("| configuration | diverged | peak tip speed (m/s) | vs ref | swing omega (rad/s) | vs ref | "
          "decay sigma (1/s) | vs ref |")
    print("|---|---|---|---|---|---|---|---|")
    for name, r in results.items():
        s = r["stats"]
        print(f"| {name} | {r['diverged']} | {summarise(s['peak_tip_speed'])} | "
              f"{paired(s['peak_tip_speed'], ref['peak_tip_speed'])} | {summarise(s['omega'])} | "
              f"{paired(s['omega'], ref['omega'])} | {summarise(s['decay'])} | "
              f"{paired_abs(s['decay'], ref['decay'])} |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"argv": sys.argv[1:], "results": results}, fh, indent=1)


if __name__ == "__main__":
    main()
