"""The ball-joint chain cable (``CableParams(model="chain")``): model, closed-form mechanics, robustness."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from dyndlo_vision.sim import CableParams, PhysicsOptions, Scene, SceneConfig
from dyndlo_vision.sim import chain as chain_model
from dyndlo_vision.sim.scene import CABLE_NAME

G = 9.81


def _chain(**overrides: float | str) -> CableParams:
    return CableParams(model="chain", **overrides)  # type: ignore[arg-type]


def _edge_lengths(nodes: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.diff(nodes, axis=-2), axis=-1)


# ---------------------------------------------------------------------------------------------- the model
def test_chain_structure_and_nodes() -> None:
    """20 capsules (the first welded to the TCP), 19 ball joints, 21 nodes from the TCP to the free end."""
    cable = _chain()
    scene = Scene(SceneConfig(cable=cable, settle_s=0.0))
    m = scene.model
    balls = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL]
    assert len(balls) == cable.num_segments - 1
    assert m.nflex == 0
    nodes = scene.cable_nodes()
    assert nodes.shape == (cable.num_nodes, 3)
    np.testing.assert_allclose(nodes[0], scene.tcp_positions()[0], atol=1e-12)
    np.testing.assert_allclose(nodes[-1], nodes[0] + [0, 0, -cable.length_m], atol=1e-9)  # hangs straight
    np.testing.assert_allclose(_edge_lengths(nodes), cable.segment_length_m, rtol=1e-12)


@pytest.mark.parametrize("length", [0.4637291, 0.5123456789])
def test_any_length_builds_with_exact_edges(length: float) -> None:
    """Randomised cables (evaluate --randomize-cable) have lengths with many digits: the scene builds and
    its edges are the segment length to rounding error."""
    cable = _chain(length_m=length)
    scene = Scene(SceneConfig(cable=cable, settle_s=0.0))
    batch = scene.nodes_from_qpos(scene.data.qpos[None])[0]
    np.testing.assert_allclose(_edge_lengths(scene.cable_nodes()), cable.segment_length_m, rtol=1e-14)
    np.testing.assert_allclose(_edge_lengths(batch), cable.segment_length_m, rtol=1e-14)


def test_batched_kinematics_match_mujoco() -> None:
    """``nodes_from_qpos`` (NumPy, for batches) and ``cable_nodes`` (MuJoCo) agree at random poses."""
    scene = Scene(SceneConfig(cable=_chain(), settle_s=0.0))
    m, d = scene.model, scene.data
    rng = np.random.default_rng(1)
    qpos = np.tile(m.qpos0, (20, 1))
    for j in range(m.njnt):
        adr = m.jnt_qposadr[j]
        if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_BALL:
            q = rng.normal(size=(20, 4))
            qpos[:, adr:adr + 4] = q / np.linalg.norm(q, axis=1, keepdims=True)
        else:
            qpos[:, adr] = rng.normal(0, 0.2, 20)
    batch = scene.nodes_from_qpos(qpos)
    for k in range(20):
        d.qpos[:] = qpos[k]
        np.testing.assert_allclose(scene.cable_nodes(), batch[k], atol=1e-12)


def test_bending_and_twist_stiffness_per_joint() -> None:
    """Each joint resists bending with EI/l and twist with GJ/l (the twist correction actuator)."""
    cable = _chain()
    scene = Scene(SceneConfig(cable=cable, settle_s=0.0))
    m, d = scene.model, scene.data
    joint = m.joint(chain_model.joint_name(CABLE_NAME, 5))
    dof = joint.dofadr[0]
    seg = cable.segment_length_m
    for axis, expected in (((1.0, 0, 0), cable.bending_stiffness_nm2 / seg),
                           ((0, 0, 1.0), cable.torsional_stiffness_nm2 / seg)):
        mujoco.mj_resetData(m, d)
        angle = 0.01
        q = np.zeros(4)
        mujoco.mju_axisAngle2Quat(q, np.array(axis), angle)
        d.qpos[joint.qposadr[0]:joint.qposadr[0] + 4] = q
        mujoco.mj_forward(m, d)
        torque = (d.qfrc_spring + d.qfrc_actuator)[dof:dof + 3]
        k = int(np.argmax(np.abs(axis)))
        assert torque[k] == pytest.approx(-expected * angle, rel=1e-6)
    assert cable.torsional_stiffness_nm2 == pytest.approx(cable.bending_stiffness_nm2 / (1 + cable.poisson))


def test_no_contacts_between_the_cables_own_capsules() -> None:
    """Capsules collide with the floor and props (MuJoCo's default contype/conaffinity 1), not each other."""
    scene = Scene(SceneConfig(cable=_chain(), settle_s=0.0))
    m = scene.model
    cable_geoms = [g for g in range(m.ngeom) if m.geom(g).name.startswith(f"{CABLE_NAME}_geom")]
    assert len(cable_geoms) == scene.config.cable.num_segments
    floor = m.geom("floor").id
    for a in cable_geoms:
        assert (m.geom_contype[a] & m.geom_conaffinity[floor]) or (
            m.geom_contype[floor] & m.geom_conaffinity[a])
        for b in cable_geoms:
            assert not (m.geom_contype[a] & m.geom_conaffinity[b])


def test_damping_defaults_per_model() -> None:
    """Left unset, the damping takes each model's default; the quadratic term is the chain's only."""
    from dyndlo_vision.sim.cable import DEFAULT_DAMPING_QUADRATIC_S2, DEFAULT_DAMPING_S

    chain, rod = _chain(), CableParams(model="rod")
    assert (chain.damping_s, chain.damping_quadratic_s2) == (DEFAULT_DAMPING_S["chain"],
                                                             DEFAULT_DAMPING_QUADRATIC_S2["chain"])
    assert (rod.damping_s, rod.damping_quadratic_s2) == (0.002, 0.0)
    with pytest.raises(ValueError, match="chain cable only"):
        CableParams(damping_quadratic_s2=0.01, model="rod")
    scene = Scene(SceneConfig(cable=chain, settle_s=0.0))
    joint = scene.model.joint(chain_model.joint_name(CABLE_NAME, 1))
    k = chain.bending_stiffness_nm2 / chain.segment_length_m
    dof = joint.dofadr[0]
    assert scene.model.dof_damping[dof] == pytest.approx(chain.damping_s * k)
    assert scene.model.dof_dampingpoly[dof, 0] == pytest.approx(chain.damping_quadratic_s2 * k)


def test_rod_rejects_implicit_integrators() -> None:
    with pytest.raises(ValueError, match="does not support the rod cable"):
        SceneConfig(cable=CableParams(model="rod"), physics=PhysicsOptions(integrator="implicitfast"))
    SceneConfig(cable=_chain(), physics=PhysicsOptions(integrator="implicitfast"))


def test_chain_twist_armature_goes_on_the_twist_dof_only() -> None:
    physics = PhysicsOptions(twist_armature_kg_m2=1e-8)
    scene = Scene(SceneConfig(cable=_chain(), settle_s=0.0, physics=physics))
    m = scene.model
    joint = m.joint(chain_model.joint_name(CABLE_NAME, 3))
    np.testing.assert_array_equal(m.dof_armature[joint.dofadr[0]:joint.dofadr[0] + 3], [0, 0, 1e-8])


def test_c_rollout_matches_python_stepping() -> None:
    """The C rollout and ``mj_step`` in Python give the same chain states."""
    scene = Scene(SceneConfig(cable=_chain(), settle_s=0.2))
    home = scene.gripper_home[0]
    t = 0.001 * np.arange(300)
    p = home + np.stack([0.1 * np.sin(8 * t), 0 * t, 0.03 * np.sin(5 * t)], axis=1)
    v = np.gradient(p, 0.001, axis=0)
    scene.reset()
    qpos, _, finite = scene.rollout(scene.tcp_controls(p[:, None], v[:, None]))
    assert finite == len(t)
    scene.reset()
    for k in range(len(t)):
        scene.set_tcp_reference(p[k][None], v[k][None])
        scene.step()
    np.testing.assert_allclose(scene.cable_nodes(), scene.nodes_from_qpos(qpos[-1:])[0], atol=1e-6)


# ------------------------------------------------------------------------------ closed-form mechanics
def _pendulum_first_mode(mass: float, inertia: float, length: float, com: float, stiffness: float,
                         links: int) -> tuple[float, np.ndarray]:
    """First mode of a planar chain of ``links`` rigid links hanging from a fixed point, linearised.

    Coordinates: absolute angles from the vertical. Link i has mass ``mass``, centre of mass ``com`` below
    its top joint and inertia ``inertia`` about it; a spring ``stiffness`` acts on each relative angle (the
    first one against the fixed, vertical clamp). Returns (omega_1, mode shape).
    """
    lever = np.zeros((links, links))  # horizontal velocity of link k's COM per angle rate i
    for k in range(links):
        lever[k, :k] = length
        lever[k, k] = com
    mass_matrix = mass * lever.T @ lever + inertia * np.eye(links)
    gravity = np.diag([G * mass * (com + length * (links - 1 - i)) for i in range(links)])
    relative = np.eye(links) - np.eye(links, k=-1)
    stiffness_matrix = gravity + stiffness * relative.T @ relative
    w2, vectors = np.linalg.eig(np.linalg.solve(mass_matrix, stiffness_matrix))
    i = int(np.argmin(w2.real))
    return math.sqrt(w2.real[i]), vectors[:, i].real


def _zero_crossing_omega(x: np.ndarray, dt: float) -> float:
    x = x - x.mean()
    idx = np.flatnonzero(np.signbit(x[:-1]) != np.signbit(x[1:]))
    t = (idx + x[idx] / (x[idx] - x[idx + 1])) * dt
    return math.pi / float(np.median(np.diff(t)))


@pytest.mark.parametrize("young", [1e3, 2e6])  # bending stiffness negligible / the paper's cable
def test_hanging_chain_first_mode(young: float) -> None:
    """Started in its first mode (3 degrees), the chain swings at the discrete N-link pendulum's omega_1,
    and within 0.3 % of the continuous chain's 1.2025 sqrt(g / L') for its hanging length L' = L - l (the
    first link is clamped)."""
    cable = _chain(young_pa=young, damping_s=0.0)
    home = np.array([0.5, 0.0, 0.8])
    seg = cable.segment_length_m
    probe = Scene(SceneConfig(cable=cable, grippers_m=(tuple(home),), settle_s=0.0))
    body = probe.model.body(chain_model.body_name(CABLE_NAME, 1))
    omega_discrete, shape = _pendulum_first_mode(
        float(body.mass[0]), float(body.inertia[0]), seg, float(body.ipos[2]),
        cable.bending_stiffness_nm2 / seg, cable.num_segments - 1,
    )
    theta = math.radians(3.0) * shape / np.abs(shape).max()
    path = [home, home + [0, 0, -seg]]
    for th in theta:
        path.append(path[-1] + seg * np.array([math.sin(th), 0.0, -math.cos(th)]))
    path[-1] = path[-1] + (path[-1] - path[-2])  # a little past the end
    scene = Scene(SceneConfig(cable=cable, grippers_m=(tuple(home),), initial_path_m=tuple(map(tuple, path)),
                              settle_s=0.0))
    scene.reset()
    tip_x = []
    for _ in range(2000):
        scene.step(2)
        tip_x.append(scene.cable_nodes()[-1, 0])
    assert scene.is_finite()
    omega = _zero_crossing_omega(np.array(tip_x), 0.002)
    assert omega == pytest.approx(omega_discrete, rel=0.002), (omega, omega_discrete)  # measured 0.01 %
    continuous = 1.2025 * math.sqrt(G / (cable.length_m - seg))
    tolerance = 0.003 if young < 1e4 else 0.012  # bending stiffens the paper's cable by about 1 %
    assert omega == pytest.approx(continuous, rel=tolerance), (omega, continuous)


def _cantilever_tip_deflection(cable: CableParams) -> float:
    """Small-deflection tip sag of the chain as a horizontal cantilever: the first link clamped, joint i
    (at x_i = i l) turns by its moment over EI/l, the tip drops by the sum of turn * lever."""
    n, seg = cable.num_segments, cable.segment_length_m
    m, k = cable.mass_kg / n, cable.bending_stiffness_nm2 / seg
    x = np.arange(n) * seg
    turns = [sum(m * G * (x[j] + seg / 2 - x[i]) for j in range(i, n)) / k for i in range(1, n)]
    return float(sum(turn * (cable.length_m - x[i]) for i, turn in zip(range(1, n), turns, strict=True)))


@pytest.mark.parametrize("segments", [10, 20, 40])
def test_cantilever_static_deflection(segments: int) -> None:
    """A short stiff horizontal cantilever sags as the discrete closed form (0.2 %), and converges to the
    Euler-Bernoulli w L^4 / (8 EI) at first order: the clamped first link and the joint at its end leave out
    about 2 / N of the root's compliance (measured -19 %, -9.8 %, -5.0 % for N = 10, 20, 40)."""
    cable = _chain(length_m=0.1, num_segments=segments, mass_kg=0.002, radius_m=0.001, young_pa=8e8,
                   damping_s=0.05)
    scene = Scene(SceneConfig(cable=cable, grippers_m=((0.5, 0.0, 0.5),), cable_axis=(1.0, 0.0, 0.0),
                              settle_s=3.0))
    scene.reset()
    deflection = 0.5 - scene.cable_nodes()[-1, 2]
    assert deflection == pytest.approx(_cantilever_tip_deflection(cable), rel=0.002)
    continuum = (cable.mass_kg * G / cable.length_m) * cable.length_m**4 / (8 * cable.bending_stiffness_nm2)
    assert 0.01 < continuum / cable.length_m < 0.1  # small deflection: linear theory applies
    error = deflection / continuum - 1
    assert -2.2 / segments < error < -1.5 / segments, error


# ------------------------------------------------------------------------------------ robustness
def _random_episodes(task: str, multi_step: bool, episodes: int, seed: int = 0) -> tuple[int, int, float]:
    """(diverged episodes, MuJoCo warnings, largest relative edge-length error) under random actions."""
    from dyndlo_vision.sim import paper_cable
    from dyndlo_vision.tasks import make_env

    cable = paper_cable(0.9 if task == "vaulting" else 0.5, model="chain")
    env = make_env(task, cable=cable, multi_step=multi_step).unwrapped
    scene = env.scene
    rest = cable.segment_length_m
    stretch = [0.0]
    inner = scene.rollout

    def rollout(controls: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        qpos, qvel, finite = inner(controls)
        if finite:
            edges = _edge_lengths(scene.nodes_from_qpos(qpos[:finite]))
            stretch[0] = max(stretch[0], float(np.abs(edges / rest - 1).max()))
        return qpos, qvel, finite

    scene.rollout = rollout  # type: ignore[method-assign]
    rng = np.random.default_rng(seed)
    diverged = warnings = 0
    for ep in range(episodes):
        env.reset(seed=seed + ep)
        done = False
        info: dict = {}
        while not done:
            _, _, terminated, truncated, info = env.step(rng.uniform(-1, 1, env.action_space.shape)
                                                         .astype(np.float32))
            done = terminated or truncated
        diverged += bool(info.get("diverged"))
        warnings += int(sum(scene.data.warning[i].number for i in range(len(scene.data.warning))))
    return diverged, warnings, stretch[0]


def test_zero_stretch_under_random_multi_step_actions() -> None:
    """Rigid links: edge lengths stay at the rest length to rounding error at every physics step."""
    diverged, warnings, stretch = _random_episodes("tip-control", True, 3)
    assert diverged == 0 and warnings == 0
    assert stretch < 1e-12, stretch


@pytest.mark.slow
@pytest.mark.parametrize("task", ["tip-control", "time-oscillation", "hooking", "vaulting"])
@pytest.mark.parametrize("multi_step", [False, True])
def test_no_divergence_under_random_actions(task: str, multi_step: bool) -> None:
    """No MuJoCo warning (of any kind) in random-action episodes of every task (benchmarks/chain_robustness.py
    runs 1000 per task and mode)."""
    episodes = 2 if task == "vaulting" else 8
    diverged, warnings, stretch = _random_episodes(task, multi_step, episodes)
    assert (diverged, warnings) == (0, 0)
    assert stretch < 1e-12


# ------------------------------------------------------------------------------------ task scenes
def test_every_task_scene_builds_with_the_chain() -> None:
    """Tip control, time-oscillation (one gripper), hooking (two grippers) and vaulting (support) settle
    with the chain, the far end held where the task holds it."""
    from dyndlo_vision.sim import paper_cable
    from dyndlo_vision.tasks import make_env

    for task in ("tip-control", "time-oscillation", "hooking", "vaulting"):
        cable = paper_cable(0.9 if task == "vaulting" else 0.5, model="chain")
        env = make_env(task, cable=cable).unwrapped
        env.reset(seed=0)
        scene = env.scene
        nodes = scene.cable_nodes()
        assert nodes.shape == (cable.num_nodes, 3)
        np.testing.assert_allclose(_edge_lengths(nodes), cable.segment_length_m, rtol=1e-12)
        assert scene.is_finite()
        if scene.config.far_end == "gripper":
            assert np.linalg.norm(nodes[-1] - scene.tcp_positions()[1]) < 2e-3
        elif scene.config.far_end == "support":
            assert np.linalg.norm(nodes[-1] - np.asarray(scene.config.support_m)) < 2e-3
        assert nodes[:, 2].min() > -cable.radius_m  # not through the floor
