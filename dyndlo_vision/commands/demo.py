"""``dyndlo-vision demo``: one tip-control episode in simulation, rendered to MP4/PNG with a metrics.json."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from dyndlo_vision._atomic import write_atomic

HELP = "simulate and render one tip-control episode"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``demo``."""
    p.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--candidates", type=int, default=32, help="random-search candidates (>= 1)")


def run(args: argparse.Namespace) -> int:
    """Run one tip-control episode and write demo.mp4, demo.png and metrics.json to ``--out``."""
    import cv2
    import gymnasium as gym

    import dyndlo_vision  # noqa: F401

    if args.candidates < 1:
        raise ValueError(f"--candidates must be >= 1, got {args.candidates}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    env = gym.make("DynDLO/TipControl-v0", render_mode="rgb_array").unwrapped
    rng = np.random.default_rng(args.seed)
    # Until trained policies ship (issue 3), the demo plans with a small random search over single-step
    # actions, simulating each candidate without rendering, and replays the best one.
    best, best_dist = None, np.inf
    for _ in range(args.candidates):
        action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
        env.reset(seed=args.seed)
        _, _, _, _, info = env.step(action)
        score = info["min_distance_m"] + (1.0 if any(info["avoid"].values()) else 0.0)
        if score < best_dist:
            best, best_dist = action, score
    env.reset(seed=args.seed)
    env._plan(best)  # noqa: SLF001  (render while stepping the physics in 40 ms slices)
    frames = [env.render()]
    total = env.trajectory.t_end + env.task.settle_s
    while env.scene.time < total - 1e-9:
        env._simulate(env._steps_per_control)  # noqa: SLF001
        frames.append(env.render())
    terms, success, info = env.task.evaluate(env.scene, env.goal, env._monitor, True)  # noqa: SLF001
    env.close()
    h, w = frames[0].shape[:2]

    def write_video(path: str) -> None:
        writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (w, h))
        if not writer.isOpened():
            raise RuntimeError(f"OpenCV cannot write MP4 to {path}")
        for frame in frames:
            writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        writer.release()

    write_atomic(out / "demo.mp4", write_video)
    strip = np.hstack([frames[i] for i in np.linspace(0, len(frames) - 1, 4).astype(int)])
    write_atomic(out / "demo.png", lambda p: cv2.imwrite(p, cv2.cvtColor(strip, cv2.COLOR_RGB2BGR)))
    metrics = {
        "success": bool(success),
        "min_distance_to_target_m": float(info["min_distance_m"]),
        "reward": float(sum(terms.values())),
        "reward_terms": terms,
        "avoid": env._monitor.avoid,  # noqa: SLF001
        "goal_m": env.goal.tolist(),
        "planner": f"random search over {args.candidates} single-step actions (no trained policy yet)",
        "frames": len(frames),
    }
    write_atomic(out / "metrics.json", lambda p: Path(p).write_text(json.dumps(metrics, indent=2)))
    print(json.dumps({k: metrics[k] for k in ("success", "min_distance_to_target_m", "reward")}))
    print(f"wrote {out / 'demo.mp4'}, {out / 'demo.png'}, {out / 'metrics.json'}")
    return 0
