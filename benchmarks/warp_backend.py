"""Can MuJoCo Warp run the task scenes? Model loading, a CPU-device comparison with MuJoCo, a GPU throughput.

For every task's scene (the nominal cable, the scenes training uses): ``mujoco_warp.put_model`` (it raises for
a feature it does not support), then a short rollout from the settled state with random TCP references (the
same controls in both engines), on Warp's CPU device, against MuJoCo's ``mj_step``. MuJoCo's ``discrete``
integrator is not one Warp has, so each scene is also compared with both engines on ``implicitfast``, the
integrator closest to it that both run. Reports per scene: whether it loads, the largest difference of the
cable's node positions and of qpos after 0.1 s / the whole rollout, and NaNs.

``--gpu`` also measures physics steps per second at 1 024 - 8 192 worlds on a CUDA device (a graph-captured
``mujoco_warp.step``), against ``mujoco.batch`` on this machine's CPU cores in the same run.

Warp is not a dependency of the package: install it beside it (``pip install mujoco-warp``).

    python benchmarks/warp_backend.py [--quick] [--steps 200] [--gpu --worlds 1024 4096 8192]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import replace
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from dyndlo_vision.sim import PhysicsOptions, Scene  # noqa: E402
from dyndlo_vision.sim.batch import MujocoBatch  # noqa: E402
from dyndlo_vision.tasks import TASKS  # noqa: E402
from dyndlo_vision.tasks.registry import make_task  # noqa: E402


def scenes(integrator: str | None) -> dict[str, Scene]:
    """Each task's scene (nominal cable), optionally with another integrator."""
    out = {}
    for name in TASKS:
        config = make_task(name).scene_config()
        if integrator is not None:
            config = replace(config, physics=replace(config.physics, integrator=integrator))
        out[name] = Scene(config)
    return out


def random_controls(scene: Scene, steps: int, rng: np.random.Generator) -> np.ndarray:
    """Smooth random TCP references (a sum of sines, up to about 1 m/s) as actuator controls, (steps, nu)."""
    t = scene.timestep * np.arange(steps)
    amp = rng.uniform(0.02, 0.08, (3, 3))
    freq = rng.uniform(2.0, 12.0, (3, 3))
    offset = np.stack([np.sum(amp[k] * np.sin(np.outer(t, freq[k])), axis=1) for k in range(3)], axis=1)
    vel = np.stack([np.sum(amp[k] * freq[k] * np.cos(np.outer(t, freq[k])), axis=1) for k in range(3)],
                   axis=1)
    home = scene.gripper_home
    p = home[None] + offset[:, None]
    v = np.broadcast_to(vel[:, None], p.shape)
    return scene.tcp_controls(p, v)


def mujoco_rollout(scene: Scene, controls: np.ndarray) -> np.ndarray:
    m, d = scene.model, scene.data
    scene.reset()
    out = np.empty((controls.shape[0], m.nq))
    for k, u in enumerate(controls):
        d.ctrl[:] = u
        mujoco.mj_step(m, d)
        out[k] = d.qpos
    return out


def warp_rollout(scene: Scene, controls: np.ndarray, device: str) -> np.ndarray:
    import mujoco_warp as mjw
    import warp as wp

    scene.reset()
    with wp.ScopedDevice(device):
        m = mjw.put_model(scene.model)
        d = mjw.put_data(scene.model, scene.data, nconmax=64, njmax=256)
        out = np.empty((controls.shape[0], scene.model.nq))
        for k, u in enumerate(controls):
            wp.copy(d.ctrl, wp.array(u[None].astype(np.float32), dtype=float))
            mjw.step(m, d)
            out[k] = d.qpos.numpy()[0]
    return out


def compare(steps: int, device: str, rng: np.random.Generator) -> list[dict[str, Any]]:
    rows = []
    for integrator in (None, "implicitfast"):
        for name, scene in scenes(integrator).items():
            row: dict[str, Any] = {"task": name, "integrator": scene.model.opt.integrator,
                                   "integrator_name": integrator or PhysicsOptions().integrator}
            try:
                import mujoco_warp as mjw

                mjw.put_model(scene.model)
                row["put_model"] = "ok"
            except Exception as err:  # noqa: BLE001  what Warp refuses is the finding
                row["put_model"] = f"{type(err).__name__}: {err}"
                rows.append(row)
                print(json.dumps(row), flush=True)
                continue
            controls = random_controls(scene, steps, rng)
            reference = mujoco_rollout(scene, controls)
            start = time.perf_counter()
            try:
                warp = warp_rollout(scene, controls, device)
            except Exception as err:  # noqa: BLE001
                row["rollout"] = f"{type(err).__name__}: {err}"
                rows.append(row)
                print(json.dumps(row), flush=True)
                continue
            row["warp_s"] = round(time.perf_counter() - start, 1)
            nodes_ref = scene.nodes_from_qpos(reference)
            finite = np.all(np.isfinite(warp), axis=1)
            row["warp_nan_from_step"] = None if finite.all() else int(np.argmin(finite))
            good = warp[finite] if not finite.all() else warp
            nodes_warp = scene.nodes_from_qpos(good)
            early = min(len(good), int(round(0.1 / scene.timestep)))
            diff = np.linalg.norm(nodes_warp - nodes_ref[: len(good)], axis=2).max(axis=1)
            row["node_diff_m_at_0.1s"] = float(diff[:early].max()) if early else None
            row["node_diff_m_max"] = float(diff.max()) if len(diff) else None
            row["qpos_diff_max"] = float(np.abs(good - reference[: len(good)]).max()) if len(good) else None
            row["steps"] = steps
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def gpu_throughput(worlds: list[int], steps: int) -> list[dict[str, Any]]:
    """Physics steps per second of the tip-control scene on the CUDA device, at several world counts."""
    import mujoco_warp as mjw
    import warp as wp

    scene = scenes(None)["tip-control"]
    scene.reset()
    rows = []
    for nworld in worlds:
        with wp.ScopedDevice("cuda:0"):
            m = mjw.put_model(scene.model)
            d = mjw.put_data(scene.model, scene.data, nworld=nworld, nconmax=16, njmax=64)
            mjw.step(m, d)  # compile
            with wp.ScopedCapture() as capture:
                mjw.step(m, d)
            wp.synchronize()
            start = time.perf_counter()
            for _ in range(steps):
                wp.capture_launch(capture.graph)
            wp.synchronize()
            wall = time.perf_counter() - start
        rows.append({"worlds": nworld, "steps": steps, "sim_steps_per_s": nworld * steps / wall,
                     "nan": bool(np.isnan(d.qpos.numpy()).any())})
        print(json.dumps(rows[-1]), flush=True)
    cpu = MujocoBatch(scene.model, 64, nthread=0)
    cpu.set_states(np.arange(64), np.tile(scene.reset_state(), (64, 1)))
    controls = np.tile(scene.data.ctrl, (64, steps, 1))
    start = time.perf_counter()
    cpu.rollout(np.arange(64), controls)
    wall = time.perf_counter() - start
    rows.append({"cpu_batch_sims": 64, "threads": cpu.nthread, "sim_steps_per_s": 64 * steps / wall})
    print(json.dumps(rows[-1]), flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=200, help="physics steps of each comparison rollout")
    parser.add_argument("--quick", action="store_true", help="20 steps (checks the script runs)")
    parser.add_argument("--device", default="cpu", help="Warp device of the comparison (default cpu)")
    parser.add_argument("--gpu", action="store_true", help="also measure throughput on cuda:0")
    parser.add_argument("--worlds", type=int, nargs="+", default=[1024, 4096, 8192])
    args = parser.parse_args()
    try:
        import mujoco_warp  # noqa: F401
    except ImportError:
        print(json.dumps({"mujoco_warp": "not installed (pip install mujoco-warp)"}))
        return
    import warp as wp

    versions = f"mujoco {mujoco.__version__}, warp {wp.__version__}"
    print(f"# {platform.machine()}, {os.cpu_count()} cpus, {versions}")
    steps = 20 if args.quick else args.steps
    compare(steps, args.device, np.random.default_rng(0))
    if args.gpu:
        gpu_throughput(args.worlds, 20 if args.quick else 500)


if __name__ == "__main__":
    main()
