"""Choose the integrator and timestep of the cable by measurement: stability, accuracy and speed.

Every configuration drives the TCP of the tip-control scene (50 cm / 20-segment cable) along the same
whipping reference (planar, peak TCP speed ``--vmax``), records the free tip at 100 Hz, and compares it with
a reference run (``discrete`` at 0.125 ms). Speed is simulated seconds per wall second on one core.

    python benchmarks/integrator_choice.py [--vmax 1.8] [--segments 20] [--quick]

``--quick``: one repeat, ``discrete`` and ``Euler`` at 1 ms only.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")

import mujoco  # noqa: E402

from dyndlo_vision.sim import CableParams, PhysicsOptions, Scene, SceneConfig  # noqa: E402


def whip_reference(t: np.ndarray, vmax: float) -> tuple[np.ndarray, np.ndarray]:
    """A planar whip: x and z follow smooth sinusoids whose combined peak speed is ``vmax``."""
    w = 2 * np.pi * 1.25
    env = np.clip(t / 0.4, 0, 1) ** 2 * (3 - 2 * np.clip(t / 0.4, 0, 1))  # smooth start
    ax = vmax / w / 1.05
    x = ax * np.sin(w * t) * env
    z = 0.5 * ax * (1 - np.cos(w * t)) * env
    vx = np.gradient(x, t)
    vz = np.gradient(z, t)
    return np.stack([x, np.zeros_like(x), z], 1), np.stack([vx, np.zeros_like(vx), vz], 1)


def follow_reference(scene: Scene, pos: np.ndarray, vel: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Drive the TCP along per-step references; the free tip at 100 Hz, and the wall and CPU seconds taken."""
    every = max(1, int(round(0.01 / scene.timestep)))  # 100 Hz samples, common to every dt used
    tips = []
    wall0, cpu0 = time.perf_counter(), time.process_time()
    for k in range(len(pos)):
        scene.set_tcp_reference(pos[k], vel[k])
        scene.step()
        if (k + 1) % every == 0:
            tips.append(scene.cable_nodes()[-1].copy())
    return np.array(tips), time.perf_counter() - wall0, time.process_time() - cpu0


def run(options: PhysicsOptions, segments: int, vmax: float, duration: float = 2.0) -> dict:
    cable = CableParams(num_segments=segments)
    scene = Scene(SceneConfig(cable=cable, physics=options, settle_s=0.5))
    scene.reset()
    dt = scene.timestep
    n = int(round(duration / dt))
    t = np.arange(n) * dt
    pos, vel = whip_reference(t, vmax)
    pos = pos + scene.gripper_home[0]
    tips, wall, _ = follow_reference(scene, pos, vel)
    # MuJoCo resets a diverging simulation by itself, so a finite state at the end does not mean it was
    # stable: any bad position, velocity or acceleration warning (settling included) means it was not.
    warning = mujoco.mjtWarning
    bad = (warning.mjWARN_BADQPOS, warning.mjWARN_BADQVEL, warning.mjWARN_BADQACC)
    diverged = any(scene.data.warning[int(w)].number > 0 for w in bad)
    return {"ok": scene.is_finite() and not diverged, "rate": duration / wall, "tips": tips}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--vmax", type=float, default=1.8, help="peak TCP speed, m/s (paper v_max: 1.8)")
    parser.add_argument("--segments", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3, help="speed repeats (median reported)")
    parser.add_argument("--quick", action="store_true", help="one repeat, discrete and Euler at 1 ms")
    args = parser.parse_args()
    configurations = [
        ("discrete", [0.0005, 0.001, 0.002, 0.005]),
        ("Euler", [0.0005, 0.001, 0.002]),
        ("RK4", [0.001, 0.002]),
    ]
    if args.quick:
        args.repeats, configurations = 1, [("discrete", [0.001]), ("Euler", [0.001])]
    ref = run(PhysicsOptions(integrator="discrete", timestep_s=0.000125), args.segments, args.vmax)
    assert ref["ok"], "reference run blew up"
    print(
        f"# machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cpus;"
        f" vmax={args.vmax} m/s, {args.segments} segments, reference discrete@0.125ms"
    )
    print(
        "Whip motion is chaotic: errors grow with time for every integrator, "
        "so they are quoted at fixed times."
    )
    print(
        "| integrator | dt (ms) | stable | tip err @0.25 s (mm) | @0.5 s | @1.0 s | max 0-0.5 s "
        "| sim-s / wall-s (median) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for integrator, dts in configurations:
        for dt in dts:
            results = [
                run(PhysicsOptions(integrator=integrator, timestep_s=dt), args.segments, args.vmax)
                for _ in range(args.repeats)
            ]
            r = results[0]
            if not r["ok"]:
                print(f"| {integrator} | {dt * 1e3:g} | no | - | - | - | - | - |")
                continue
            err = np.linalg.norm(r["tips"] - ref["tips"], axis=1) * 1e3  # sample k is at (k + 1) * 10 ms
            at = [err[int(round(t / 0.01)) - 1] for t in (0.25, 0.5, 1.0)]
            rate = float(np.median([x["rate"] for x in results]))
            print(
                f"| {integrator} | {dt * 1e3:g} | yes | {at[0]:.1f} | {at[1]:.1f} | {at[2]:.1f} "
                f"| {err[:50].max():.1f} | {rate:.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
