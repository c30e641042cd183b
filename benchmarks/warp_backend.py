"""Can MuJoCo Warp run the task scenes? Model loading, a CPU-device comparison with MuJoCo, a GPU throughput.

For every task's scene (the nominal cable, as training builds it): ``mujoco_warp.put_model`` (it raises for
a feature it does not support); where it refuses the chain's dense constraint Jacobian (Warp: dense only up to
60 DOFs), the same scene with ``PhysicsOptions(jacobian="sparse")``, which in MuJoCo is the same physics
stored otherwise. Then a short rollout from the settled state with random TCP references (the same controls in
both engines) on Warp's CPU device against MuJoCo's ``mj_step`` on the same model: the largest distance of
the cable's nodes between the two after 0.1 s and over the whole rollout, and where Warp's state turned NaN.

``--gpu`` also measures physics steps per second at 1 024 - 8 192 worlds on a CUDA device (a graph-captured
``mujoco_warp.step``), against ``mujoco.batch`` on this machine's CPU cores in the same run.

Warp is not a dependency of the package: install it beside it (``pip install mujoco-warp``). Its CPU device
compiles its kernels on first use (about 10 min on 2 cores, cached in ``~/.cache/warp`` afterwards).

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

from dyndlo_vision.sim import Scene  # noqa: E402
from dyndlo_vision.sim.batch import MujocoBatch  # noqa: E402
from dyndlo_vision.tasks import TASKS  # noqa: E402
from dyndlo_vision.tasks.registry import make_task  # noqa: E402


def scenes(jacobian: str | None = None) -> dict[str, Scene]:
    """Each task's scene (nominal cable), optionally with another constraint Jacobian storage."""
    out = {}
    for name in TASKS:
        config = make_task(name).scene_config()
        if jacobian is not None:
            config = replace(config, physics=replace(config.physics, jacobian=jacobian))
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
    # Room for twice the contacts of the settled state (a cable on the floor has one per capsule and more),
    # four constraint rows per pyramidal contact, and the equality rows.
    nconmax = max(64, 2 * int(scene.data.ncon) + 32)
    with wp.ScopedDevice(device):
        m = mjw.put_model(scene.model)
        d = mjw.put_data(scene.model, scene.data, nconmax=nconmax, njmax=4 * nconmax + 32)
        out = np.empty((controls.shape[0], scene.model.nq))
        for k, u in enumerate(controls):
            wp.copy(d.ctrl, wp.array(u[None].astype(np.float32), dtype=float))
            mjw.step(m, d)
            out[k] = d.qpos.numpy()[0]
    return out


def loads(scene: Scene) -> str:
    import mujoco_warp as mjw

    try:
        mjw.put_model(scene.model)
    except Exception as err:  # noqa: BLE001  what Warp refuses is the finding
        return f"{type(err).__name__}: {err}"
    return "ok"


def compare(steps: int, device: str, rng: np.random.Generator) -> list[dict[str, Any]]:
    rows = []
    sparse = scenes("sparse")
    for name, scene in scenes().items():
        row: dict[str, Any] = {"task": name, "nv": scene.model.nv, "put_model": loads(scene)}
        if row["put_model"] != "ok":
            scene = sparse[name]
            row["put_model_sparse_jacobian"] = loads(scene)
            if row["put_model_sparse_jacobian"] != "ok":
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
        finite = np.all(np.isfinite(warp), axis=1)
        row["warp_nan_from_step"] = None if finite.all() else int(np.argmin(finite))
        good = warp[: row["warp_nan_from_step"]] if row["warp_nan_from_step"] is not None else warp
        diff = np.linalg.norm(scene.nodes_from_qpos(good) - scene.nodes_from_qpos(reference[: len(good)]),
                              axis=2).max(axis=1)
        early = min(len(good), int(round(0.1 / scene.timestep)))
        row["node_diff_m_at_0.1s"] = float(diff[:early].max()) if early else None
        row["node_diff_m_max"] = float(diff.max()) if len(diff) else None
        row["steps"] = steps
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def gpu_throughput(worlds: list[int], steps: int) -> list[dict[str, Any]]:
    """Physics steps per second of the tip-control scene on the CUDA device, at several world counts."""
    import mujoco_warp as mjw
    import warp as wp

    scene = scenes()["tip-control"]
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
