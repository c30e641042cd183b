"""The MuJoCo scene: grippers (TCPs) holding a cable (discrete elastic rod or ball-joint chain), and props.

The model is generated as MJCF from frozen configuration dataclasses, so every body, joint, geom, site,
camera and actuator has a name, and indices are looked up by name once.

Gripper control is a cascaded position-velocity loop realised by one affine MuJoCo actuator per axis:

    force = kv * (v_ref + kp * (p_ref - p) - v)  =  kv * u  - kv*kp * p  - kv * v,   u = v_ref + kp * p_ref

so the outer loop (gain kp, 1/s) turns the position error into a velocity command and the inner loop
(gain kv, N s/m) tracks it. Driving joints rather than mocap bodies matters: elastic flex attachments need
the real velocity of the body that holds them.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np
from numpy.typing import ArrayLike, NDArray

from dyndlo_vision.sim import chain as chain_model
from dyndlo_vision.sim.cable import CableParams
from dyndlo_vision.sim.physics import ROD_INTEGRATORS, PhysicsOptions

CABLE_NAME = "cable"
#: Settled initial states by scene configuration (its ``repr``, exact for the floats and tuples it holds),
#: in the order settled, at most :data:`SETTLED_CACHE_SIZE` (each a few kB).
_SETTLED: OrderedDict[str, NDArray[np.float64]] = OrderedDict()
SETTLED_CACHE_SIZE = 64
FLOOR_NAME = "floor"
#: Slices around and stacks along the spheres and capsules the renderer draws (MuJoCo's defaults: 28 and 16).
#: The cable's capsules are 1-3 px wide in the loop camera and the gripper sphere about 15 px, so 16 x 8
#: facets draw the same outline to a fifth of a pixel; off-screen software rendering of a frame is about a
#: third cheaper (``benchmarks/loop_latency.py``, docs/results.md).
RENDER_SLICES, RENDER_STACKS = 16, 8


@dataclass(frozen=True)
class GripperGains:
    """Gains of the cascaded position-velocity loop of each TCP axis (see module docstring)."""

    kp_per_s: float = 60.0
    kv_ns_per_m: float = 400.0
    mass_kg: float = 1.0


@dataclass(frozen=True)
class BoxProp:
    """A static box (e.g. the vaulting obstacle). ``size_m`` are full side lengths."""

    name: str
    center_m: tuple[float, float, float]
    size_m: tuple[float, float, float]
    rgba: tuple[float, float, float, float] = (0.3, 0.4, 0.8, 1.0)


@dataclass(frozen=True)
class CapsuleProp:
    """A static capsule between two points (e.g. the bar of a hook)."""

    name: str
    from_m: tuple[float, float, float]
    to_m: tuple[float, float, float]
    radius_m: float
    rgba: tuple[float, float, float, float] = (0.6, 0.6, 0.6, 1.0)


@dataclass(frozen=True)
class CameraPose:
    """A fixed camera: position and MuJoCo's ``xyaxes`` (its x axis, then its y axis, in world coordinates;
    it looks along minus their cross product)."""

    pos_m: tuple[float, float, float]
    xyaxes: tuple[float, float, float, float, float, float]
    fovy_deg: float = 45.0

    @classmethod
    def looking_at(
        cls, pos_m: Sequence[float], target_m: Sequence[float], fovy_deg: float = 45.0
    ) -> CameraPose:
        """A camera at ``pos_m`` aimed at ``target_m``, its image rows level (x axis horizontal).

        Raises:
            ValueError: The target is straight above or below the camera (no level x axis), or at it.
        """
        pos, target = np.asarray(pos_m, dtype=float), np.asarray(target_m, dtype=float)
        view = target - pos
        x = np.cross(view, [0.0, 0.0, 1.0])
        if np.linalg.norm(x) < 1e-9 * max(1.0, float(np.linalg.norm(view))):
            raise ValueError(
                f"a camera at {pos_m} cannot look level at {target_m} (straight up, down or at it)"
            )
        x /= np.linalg.norm(x)
        y = np.cross(x, view)
        y /= np.linalg.norm(y)
        return cls(tuple(float(v) for v in pos), (*map(float, x), *map(float, y)), fovy_deg)  # type: ignore[arg-type]


#: Name of the second loop camera (:attr:`SceneConfig.second_tracking_camera`).
SECOND_TRACKING_CAMERA_NAME = "tracking2"

#: The loop's camera for the planar tasks: 1.45 m in front of the x-z plane, looking along +y.
TRACKING_CAMERA = CameraPose((0.65, -1.45, 0.575), (1.0, 0.0, 0.0, 0.0, 0.0, 1.0))


@dataclass(frozen=True)
class SceneConfig:
    """Everything needed to build one scene.

    Attributes:
        cable: Cable parameters.
        grippers_m: Start position of each TCP (one for single arm, two for dual arm). The cable is clamped
            to the first TCP (its first edge is rigid with the gripper).
        far_end: What holds the cable's last node: ``"free"``, ``"gripper"`` (the second TCP) or
            ``"support"`` (a fixed point at ``support_m``).
        support_m: World position of the support for ``far_end="support"``.
        cable_axis: Direction in which the straight cable leaves the first TCP in the compiled model (its
            rest pose); the default hangs it straight down.
        initial_path_m: Optional polyline, starting at the first TCP, along which the cable is laid before it
            settles under gravity. ``None`` lays it straight down from the first TCP.
        settle_s: Simulated time the cable settles (grippers still) before the initial state is recorded.
        target_radius_m: Radius of the visual target marker (a mocap body, no collisions); 0 for none.
        boxes, capsules: Static collision props.
        physics: Solver settings.
        gains: TCP loop gains.
        image_size: Off-screen framebuffer (width, height) for rendering.
        tracking_camera: Pose of the "tracking" camera, the one the control loop tracks the cable from:
            position and ``xyaxes`` (MuJoCo's camera x and y axes in world coordinates). The default looks
            along +y at the x-z plane the planar tasks move in; a task whose cable lies lower or farther out
            places it to see that.
        second_tracking_camera: Pose of a second loop camera, "tracking2", for a task whose cable leaves any
            one plane (vaulting): the loop then triangulates the cable from the two views. None: no such
            camera.
    """

    cable: CableParams = field(default_factory=CableParams)
    grippers_m: tuple[tuple[float, float, float], ...] = ((0.5, 0.0, 0.6),)
    far_end: str = "free"
    support_m: tuple[float, float, float] | None = None
    initial_path_m: tuple[tuple[float, float, float], ...] | None = None
    cable_axis: tuple[float, float, float] = (0.0, 0.0, -1.0)
    settle_s: float = 1.0
    target_radius_m: float = 0.0
    boxes: tuple[BoxProp, ...] = ()
    capsules: tuple[CapsuleProp, ...] = ()
    physics: PhysicsOptions = field(default_factory=PhysicsOptions)
    gains: GripperGains = field(default_factory=GripperGains)
    image_size: tuple[int, int] = (640, 480)
    tracking_camera: CameraPose = field(default_factory=lambda: TRACKING_CAMERA)
    second_tracking_camera: CameraPose | None = None

    def __post_init__(self) -> None:
        if len(self.grippers_m) not in (1, 2):
            raise ValueError(f"expected 1 or 2 grippers, got {len(self.grippers_m)}")
        if self.far_end not in ("free", "gripper", "support"):
            raise ValueError(f"far_end={self.far_end!r}; expected 'free', 'gripper' or 'support'")
        if self.far_end == "gripper" and len(self.grippers_m) != 2:
            raise ValueError("far_end='gripper' needs two grippers")
        if not np.isfinite(self.cable_axis).all() or np.linalg.norm(self.cable_axis) < 1e-9:
            raise ValueError(f"cable_axis={self.cable_axis} must be a non-zero direction")
        if self.far_end == "support" and self.support_m is None:
            raise ValueError("far_end='support' needs support_m")
        if self.cable.model == "rod" and self.physics.integrator not in ROD_INTEGRATORS:
            raise ValueError(
                f"integrator={self.physics.integrator!r} does not support the rod cable (MuJoCo 4 rejects "
                f"implicit integrators for rod elasticity); use one of {ROD_INTEGRATORS} or the chain cable"
            )

    @property
    def num_grippers(self) -> int:
        """Number of TCPs."""
        return len(self.grippers_m)


def _fmt(values: Sequence[float]) -> str:
    return " ".join(f"{float(v):.6g}" for v in values)


def gripper_name(index: int) -> str:
    """Name of the body of TCP ``index``; its joints are ``<name>_x|y|z``."""
    return f"tcp_{index}"


def _cable_rotation(config: SceneConfig) -> NDArray[np.float64]:
    """Quaternion rotating z onto ``config.cable_axis`` (the straight cable's direction at qpos0)."""
    axis = np.asarray(config.cable_axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    quat = np.zeros(4)
    mujoco.mju_quatZ2Vec(quat, axis)
    return quat


def far_end_body(config: SceneConfig) -> str:
    """Name of the body that carries the cable's last node (rod: its vertex body; chain: the last capsule)."""
    if config.cable.model == "chain":
        return chain_model.body_name(CABLE_NAME, config.cable.num_segments - 1)
    return f"{CABLE_NAME}_{config.cable.num_segments}"


def build_mjcf(config: SceneConfig) -> str:
    """Return the MJCF text of the scene described by ``config``.

    Rod: in this text the cable's flexcomp sits in the world body with its first two points pinned to the
    world; :func:`build_spec` moves those points onto the first TCP, which is how :class:`Scene` compiles it.
    Chain: the capsules are nested in the first TCP's body (``dyndlo_vision.sim.chain``).
    """
    cable = config.cable
    g = config.gains
    width, height = config.image_size
    seg = cable.segment_length_m
    bodies = []
    flex = ""
    chain_xml = ""
    is_chain = cable.model == "chain"
    for i, pos in enumerate(config.grippers_m):
        name = gripper_name(i)
        if i == 0 and is_chain:
            chain_xml = chain_model.chain_bodies_mjcf(cable, CABLE_NAME, _cable_rotation(config))
        elif i == 0:
            # The grid runs along its local x axis, centred on `pos`: rotate x onto cable_axis and shift the
            # grid so node 0 sits at the TCP.
            axis = np.asarray(config.cable_axis, dtype=float)
            axis = axis / np.linalg.norm(axis)
            quat = np.zeros(4)
            mujoco.mju_quatZ2Vec(quat, axis)  # z -> axis
            to_x = np.array([np.cos(-np.pi / 4), 0.0, np.sin(-np.pi / 4), 0.0])  # -90 deg about y: x -> z
            q = np.zeros(4)
            mujoco.mju_mulQuat(q, quat, to_x)
            centre = np.asarray(pos, dtype=float) + axis * cable.length_m / 2
            # Inextensibility: discrete integration takes any constraint time constant (it is implicit), and
            # 0.5 ms keeps the stretch of a 1.8 m/s whip near 1%; explicit integrators need >= 2 timesteps.
            implicit = config.physics.integrator == "discrete"
            edge_timeconst = 0.0005 if implicit else 2 * config.physics.timestep_s
            flex = f"""
    <flexcomp name="{CABLE_NAME}" type="grid" dim="1" count="{cable.num_nodes} 1 1" spacing="{seg:.9g} 1 1"
              mass="{cable.mass_kg:.9g}" radius="{cable.radius_m:.9g}" rgba="{_fmt(cable.rgba)}"
              pos="{" ".join(f"{v:.12g}" for v in centre)}" quat="{_fmt(q)}">
      <pin id="0 1"/>
      <edge equality="true" solref="{edge_timeconst:.6g} 1"
            solimp="0.99 0.9999 0.001"/>
      <elasticity young="{cable.young_pa:.9g}" poisson="{cable.poisson:.6g}"
                  damping="{cable.damping_s:.6g}"/>
      <contact selfcollide="none" condim="3" friction="0.6" solref="0.005 1"/>
    </flexcomp>"""
        bodies.append(f"""
    <body name="{name}" pos="{_fmt(pos)}" gravcomp="1">
      <joint name="{name}_x" type="slide" axis="1 0 0"/>
      <joint name="{name}_y" type="slide" axis="0 1 0"/>
      <joint name="{name}_z" type="slide" axis="0 0 1"/>
      <geom name="{name}_geom" type="sphere" size="0.02" mass="{g.mass_kg}" rgba="0.2 0.2 0.2 1"
            contype="0" conaffinity="0"/>
      <site name="{name}_site" size="0.005"/>{chain_xml if i == 0 else ""}
    </body>""")
    props = []
    if config.far_end == "support":
        assert config.support_m is not None
        props.append(f"""
    <body name="support" pos="{_fmt(config.support_m)}">
      <geom name="support_geom" type="sphere" size="0.012" rgba="0.2 0.2 0.2 1" contype="0" conaffinity="0"/>
    </body>""")
    if config.target_radius_m > 0:
        props.append(f"""
    <body name="target" mocap="true" pos="0.7 0 0.3">
      <geom name="target_geom" type="sphere" size="{config.target_radius_m:.6g}" rgba="0.1 0.7 0.2 0.6"
            contype="0" conaffinity="0"/>
    </body>""")
    for box in config.boxes:
        half = [s / 2 for s in box.size_m]
        props.append(
            f'\n    <geom name="{box.name}" type="box" pos="{_fmt(box.center_m)}" size="{_fmt(half)}" '
            f'rgba="{_fmt(box.rgba)}"/>'
        )
    for cap in config.capsules:
        props.append(
            f'\n    <geom name="{cap.name}" type="capsule" fromto="{_fmt(cap.from_m + cap.to_m)}" '
            f'size="{cap.radius_m:.6g}" rgba="{_fmt(cap.rgba)}"/>'
        )
    actuators = []
    for i in range(config.num_grippers):
        for axis in "xyz":
            jn = f"{gripper_name(i)}_{axis}"
            actuators.append(
                f'\n    <general name="{jn}_servo" joint="{jn}" gainprm="{g.kv_ns_per_m}" '
                f'biastype="affine" biasprm="0 {-g.kv_ns_per_m * g.kp_per_s} {-g.kv_ns_per_m}"/>'
            )
    if is_chain:
        actuators.append(chain_model.chain_actuators_mjcf(cable, CABLE_NAME))
    equality = ""
    last = far_end_body(config)
    if config.far_end == "gripper":
        equality = f'\n    <connect name="far_end" body1="{gripper_name(1)}" body2="{last}" anchor="0 0 0"/>'
    elif config.far_end == "support":
        equality = f'\n    <connect name="far_end" body1="support" body2="{last}" anchor="0 0 0"/>'
    world_bodies = "".join(bodies) + flex + "".join(props)
    tc = config.tracking_camera
    second = ""
    if config.second_tracking_camera is not None:
        t2 = config.second_tracking_camera
        second = (f'\n    <camera name="{SECOND_TRACKING_CAMERA_NAME}" pos="{_fmt(t2.pos_m)}"'
                  f' xyaxes="{_fmt(t2.xyaxes)}" fovy="{t2.fovy_deg:g}"/>')
    return f"""<mujoco model="dyndlo">
  <compiler autolimits="true"/>
  <option {config.physics.to_mjcf(cable.model)}/>
  <visual>
    <global offwidth="{width}" offheight="{height}"/>
    <headlight ambient="0.35 0.35 0.35" diffuse="0.5 0.5 0.5"/>
    <quality shadowsize="0" offsamples="0" numslices="{RENDER_SLICES}" numstacks="{RENDER_STACKS}"/>
  </visual>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.82 0.82 0.82" rgb2="0.78 0.78 0.78"
             width="256" height="256"/>
    <material name="floor" texture="grid" texrepeat="8 8"/>
  </asset>
  <worldbody>
    <light name="key" pos="0.5 -1 2.5" dir="0 0.4 -1" diffuse="0.6 0.6 0.6"/>
    <geom name="{FLOOR_NAME}" type="plane" size="3 3 0.1" material="floor"/>
    <camera name="front" pos="0.55 -1.7 0.45" xyaxes="1 0 0 0 0 1" fovy="45"/>
    <camera name="tracking" pos="{_fmt(tc.pos_m)}" xyaxes="{_fmt(tc.xyaxes)}" fovy="{tc.fovy_deg:g}"/>{second}
    <camera name="oblique" pos="1.6 -1.4 1.1" xyaxes="0.7 0.71 0 -0.25 0.25 0.93" fovy="45"/>{world_bodies}
  </worldbody>
  <equality>{equality}
  </equality>
  <actuator>{"".join(actuators)}
  </actuator>
</mujoco>
"""


def build_spec(config: SceneConfig) -> mujoco.MjSpec:
    """Return the scene as an ``mujoco.MjSpec``, its cable held by the first TCP.

    :func:`build_mjcf` places the cable's flexcomp in the world body, so its node bodies are children of the
    world (their slide joints measure world positions) and its two pinned points belong to the world. Here
    those two points are moved onto the first TCP body, which clamps the cable's first edge to the gripper.

    Why not declare the flexcomp inside the TCP body: its node bodies would then be children of the TCP and
    every node's Jacobian would involve the TCP's joints, which sends MuJoCo's implicit rod stiffness through
    its general (attachment-Jacobian) assembly; with nodes on world-axis slide joints of their own it
    assembles 3x3 vertex blocks instead, faster per step.
    """
    spec = mujoco.MjSpec.from_string(build_mjcf(config))
    if config.cable.model == "chain":
        return spec
    flex = spec.flex(CABLE_NAME)
    bodies = list(flex.vertbody)
    verts = np.array(flex.vert, dtype=float).reshape(-1, 3)
    tcp = np.asarray(spec.body(gripper_name(0)).pos, dtype=float)
    pinned = [i for i, b in enumerate(bodies) if b == "world"]
    if pinned != [0, 1]:
        raise RuntimeError(f"expected the cable's points 0 and 1 pinned to the world, got {pinned}")
    for i in pinned:
        bodies[i] = gripper_name(0)
        verts[i] -= tcp
    flex.vertbody = bodies
    flex.vert = verts.ravel().tolist()
    return spec


class Scene:
    """A compiled scene with named accessors and a recorded, settled initial state.

    Attributes:
        config: The configuration it was built from.
        model: The ``mujoco.MjModel``.
        data: The ``mujoco.MjData``.
    """

    def __init__(self, config: SceneConfig) -> None:
        self.config = config
        try:
            self.model = build_spec(config).compile()
        except ValueError as exc:  # MuJoCo reports compile errors as ValueError
            raise ValueError(f"the scene does not compile: {exc}") from exc
        m = self.model
        self._is_chain = config.cable.model == "chain"
        if config.physics.twist_armature_kg_m2 > 0:
            if self._is_chain:
                # The third DOF of a ball joint rotates about the child's z axis: the capsule's own axis.
                twist = [m.joint(chain_model.joint_name(CABLE_NAME, i)).dofadr[0] + 2
                         for i in range(1, config.cable.num_segments)]
            else:
                # MuJoCo names the rod's per-edge twist hinges <flex name>_twist_<edge>.
                prefix = f"{CABLE_NAME}_twist"
                twist = [m.jnt_dofadr[j] for j in range(m.njnt) if m.joint(j).name.startswith(prefix)]
            m.dof_armature[twist] = config.physics.twist_armature_kg_m2
            mujoco.mj_setConst(m, mujoco.MjData(m))  # the mass matrix of simple bodies is precomputed
        self.data = mujoco.MjData(m)
        self._tcp_qpos = np.array(
            [[m.joint(f"{gripper_name(i)}_{a}").qposadr[0] for a in "xyz"] for i in range(self.num_grippers)]
        )
        self._tcp_dof = np.array(
            [[m.joint(f"{gripper_name(i)}_{a}").dofadr[0] for a in "xyz"] for i in range(config.num_grippers)]
        )
        self._tcp_act = np.array(
            [[m.actuator(f"{gripper_name(i)}_{a}_servo").id for a in "xyz"] for i in range(self.num_grippers)]
        )
        self._tcp_home = np.array(config.grippers_m, dtype=float)
        self._kp = config.gains.kp_per_s
        self._vert_num = config.cable.num_nodes
        self._target_mocap = int(m.body("target").mocapid[0]) if config.target_radius_m > 0 else -1
        if config.far_end != "free":
            # The connect constraint's second anchor is computed from qpos0, where the cable is straight; put
            # it at the last node itself (rod: the vertex body's origin; chain: the last capsule's free end)
            # so that the node, not a point offset from it, is held.
            eq = m.equality("far_end").id
            m.eq_data[eq, 3:6] = [0.0, 0.0, config.cable.segment_length_m] if self._is_chain else 0.0
        self._state_spec = mujoco.mjtState.mjSTATE_INTEGRATION
        self._chain: chain_model.ChainKinematics | None = None
        if self._is_chain:
            self._chain = chain_model.ChainKinematics(
                m, CABLE_NAME, config.cable.num_segments, config.cable.segment_length_m, gripper_name(0)
            )
            if self._chain.check(np.random.default_rng(0)) > 1e-9:
                raise RuntimeError("the chain's batched kinematics disagree with MuJoCo's")
        else:
            self._flex_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_FLEX, CABLE_NAME)
            self._vert_adr = int(m.flex_vertadr[self._flex_id])
            self._node_offset, self._node_jacobian = self._linear_node_map()
        self._rollout: Any = None
        self._initial_state = self._settle()

    def _linear_node_map(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Cable node positions as an affine function of qpos: ``nodes = offset + qpos @ jacobian``.

        Exact because every body the nodes hang from moves on slide joints only (TCP and node translations;
        the twist hinges carry no node). Checked here against forward kinematics at a random configuration.
        """
        m = self.model
        d = mujoco.MjData(m)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_flex(m, d)
        base = d.flexvert_xpos[self._vert_adr : self._vert_adr + self._vert_num].copy()
        jac = np.zeros((m.nq, self._vert_num, 3))
        for j in range(m.nq):
            d.qpos[:] = 0.0
            d.qpos[j] = 1.0
            mujoco.mj_kinematics(m, d)
            mujoco.mj_flex(m, d)
            jac[j] = d.flexvert_xpos[self._vert_adr : self._vert_adr + self._vert_num] - base
        d.qpos[:] = np.random.default_rng(0).normal(0.0, 0.3, m.nq)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_flex(m, d)
        predicted = base + np.einsum("q,qnk->nk", d.qpos, jac)
        actual = d.flexvert_xpos[self._vert_adr : self._vert_adr + self._vert_num]
        if np.abs(predicted - actual).max() > 1e-9 or not np.any(jac):
            raise RuntimeError("cable nodes are not affine in qpos; batch rollouts are not supported")
        return base, jac.reshape(m.nq, -1)

    # ------------------------------------------------------------------ state
    def _settle(self) -> NDArray[np.float64]:
        """Lay the cable along the initial path, let it settle, and return the full integration state.

        Settling is deterministic, so a configuration settled before in this process is not settled again
        (:data:`_SETTLED`): a vaulting cable on the floor takes about 1 500 steps, 2 s of CPU.
        """
        key = repr(self.config)
        cached = _SETTLED.get(key)
        if cached is not None:
            state = cached.copy()
            mujoco.mj_resetData(self.model, self.data)
            mujoco.mj_setState(self.model, self.data, state, self._state_spec)
            mujoco.mj_forward(self.model, self.data)
            return state
        state = self._settle_afresh()
        _SETTLED[key] = state.copy()
        while len(_SETTLED) > SETTLED_CACHE_SIZE:
            _SETTLED.popitem(last=False)  # the oldest settled
        return state

    def _settle_afresh(self) -> NDArray[np.float64]:
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        self.set_tcp_reference(self._tcp_home, np.zeros_like(self._tcp_home))
        self._place_cable_along_path()
        mujoco.mj_forward(m, d)
        nsteps = int(round(self.config.settle_s / m.opt.timestep))
        for _ in range(nsteps):
            mujoco.mj_step(m, d)
        if not self.is_finite():
            raise ValueError(
                f"the cable is unstable while settling with {self.config.cable} and {self.config.physics}"
            )
        d.qvel[:] = 0.0
        d.time = 0.0
        mujoco.mj_forward(m, d)
        state = np.empty(mujoco.mj_stateSize(m, self._state_spec))
        mujoco.mj_getState(m, d, state, self._state_spec)
        return state

    def _place_cable_along_path(self) -> None:
        """Move the free nodes (via their slide joints) onto the initial path, resampled by arc length.

        Chain: the capsules follow the path instead, each link's far end on the path at one segment length
        (chord) from its start (:func:`dyndlo_vision.sim.chain.walk_polyline`), without twist.
        """
        path = self.config.initial_path_m
        if path is None:
            return
        pts = np.asarray(path, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
            raise ValueError(f"initial_path_m must be a polyline of >= 2 points (M, 3), got {pts.shape}")
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(seg)])
        cable = self.config.cable
        if arc[-1] < cable.length_m - 1e-9:
            raise ValueError(
                f"initial_path_m is {arc[-1]:.3f} m long, shorter than the cable ({cable.length_m} m)"
            )
        if self._is_chain:
            self._place_chain_along(pts)
            return
        s = np.linspace(0.0, cable.length_m, cable.num_nodes)
        target = np.stack([np.interp(s, arc, pts[:, k]) for k in range(3)], axis=1)
        m, d = self.model, self.data
        mujoco.mj_kinematics(m, d)
        for node in range(2, cable.num_nodes):  # nodes 0 and 1 are clamped to the gripper
            body = m.body(f"{CABLE_NAME}_{node}")
            jadr = body.jntadr[0]
            for k in range(3):
                qadr = m.jnt_qposadr[jadr + k]
                axis = m.jnt_axis[jadr + k]
                d.qpos[qadr] = float(np.dot(axis, target[node] - (d.xpos[body.id] - d.qpos[qadr] * axis)))
        mujoco.mj_kinematics(m, d)

    def _place_chain_along(self, pts: NDArray[np.float64]) -> None:
        m, d = self.model, self.data
        cable = self.config.cable
        mujoco.mj_kinematics(m, d)
        first = m.body(chain_model.body_name(CABLE_NAME, 0)).id
        node0, rot0 = d.xpos[first].copy(), d.xquat[first].copy()
        # The first capsule is clamped to the TCP: node 1 is where it ends, whatever the path.
        node1 = node0 + d.xmat[first].reshape(3, 3) @ [0.0, 0.0, cable.segment_length_m]
        seg_len = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        # Start the walk at the path point closest to node 1.
        best, best_dist = (0, node1), np.inf
        for j in range(len(pts) - 1):
            if seg_len[j] <= 0:
                continue
            t = float(np.clip(np.dot(node1 - pts[j], pts[j + 1] - pts[j]) / seg_len[j] ** 2, 0.0, 1.0))
            p = pts[j] + t * (pts[j + 1] - pts[j])
            if np.linalg.norm(p - node1) < best_dist:
                best, best_dist = (j, p), float(np.linalg.norm(p - node1))
        rest = chain_model.walk_polyline(pts, best[1], best[0], cable.segment_length_m,
                                         cable.num_segments - 1)
        nodes = np.vstack([node0, node1, rest])
        quats = chain_model.ball_quats_along(nodes, rot0)
        for i, q in enumerate(quats, start=1):
            adr = m.joint(chain_model.joint_name(CABLE_NAME, i)).qposadr[0]
            d.qpos[adr:adr + 4] = q
        mujoco.mj_kinematics(m, d)

    def reset(self) -> None:
        """Restore the settled initial state (time 0, everything at rest)."""
        mujoco.mj_setState(self.model, self.data, self._initial_state, self._state_spec)
        self.data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number = 0
        self.set_tcp_reference(self._tcp_home, np.zeros_like(self._tcp_home))
        mujoco.mj_forward(self.model, self.data)

    # ------------------------------------------------------------------ reads
    @property
    def time(self) -> float:
        """Simulated time in seconds."""
        return float(self.data.time)

    @property
    def timestep(self) -> float:
        """Physics timestep in seconds."""
        return float(self.model.opt.timestep)

    @property
    def num_grippers(self) -> int:
        """Number of TCPs."""
        return self.config.num_grippers

    @property
    def gripper_home(self) -> NDArray[np.float64]:
        """Start positions of the TCPs, (n_g, 3)."""
        return self._tcp_home.copy()

    def tcp_positions(self) -> NDArray[np.float64]:
        """World positions of the TCPs, (n_g, 3)."""
        return self._tcp_home + self.data.qpos[self._tcp_qpos]

    def tcp_velocities(self) -> NDArray[np.float64]:
        """World linear velocities of the TCPs, (n_g, 3)."""
        return self.data.qvel[self._tcp_dof].copy()

    def cable_nodes(self) -> NDArray[np.float64]:
        """World positions of the cable nodes from the held end to the far end, (N, 3).

        Computed from the current ``qpos`` (``mjData.flexvert_xpos`` and ``xpos`` lag one step behind after
        ``mj_step``). Chain: the ball-joint positions, then the last capsule's free end.
        """
        return self.nodes_from_qpos(self.data.qpos[None])[0]

    # ------------------------------------------------------------------ writes
    def set_tcp_reference(self, position: ArrayLike, velocity: ArrayLike) -> None:
        """Set the reference position and velocity of every TCP, each (n_g, 3)."""
        p = np.asarray(position, dtype=float).reshape(1, self.num_grippers, 3)
        v = np.asarray(velocity, dtype=float).reshape(1, self.num_grippers, 3)
        self.data.ctrl[:] = self.tcp_controls(p, v)[0]

    def set_target(self, position: ArrayLike) -> None:
        """Move the visual target marker."""
        if self._target_mocap < 0:
            raise ValueError("this scene has no target marker (target_radius_m = 0)")
        self.data.mocap_pos[self._target_mocap] = np.asarray(position, dtype=float)

    def tcp_controls(self, positions: ArrayLike, velocities: ArrayLike) -> NDArray[np.float64]:
        """Actuator controls that make the TCPs follow references, each (K, n_g, 3) -> (K, nu)."""
        p = np.asarray(positions, dtype=float)
        v = np.asarray(velocities, dtype=float)
        ctrl = np.tile(self.data.ctrl, (p.shape[0], 1))
        ctrl[:, self._tcp_act.ravel()] = (v + self._kp * (p - self._tcp_home)).reshape(p.shape[0], -1)
        return ctrl

    def rollout(self, controls: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
        """Step once per row of ``controls`` (K, nu) in MuJoCo's C rollout, without Python per step.

        The scene ends in the state after the last step, as if :meth:`step` had been called K times with
        the same controls (the two agree to solver tolerance).

        Returns:
            qpos (K, nq) and qvel (K, nv) after each step, and the number of leading steps that stayed
            finite (K unless the simulation blew up; MuJoCo then resets the state, detected from the time).
        """
        from mujoco import rollout

        m, d = self.model, self.data
        if self._rollout is None:
            self._rollout = rollout.Rollout(nthread=0)
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        state0 = np.empty(mujoco.mj_stateSize(m, spec))
        mujoco.mj_getState(m, d, state0, spec)
        k = controls.shape[0]
        mocap = (d.mocap_pos.copy(), d.mocap_quat.copy())  # not part of the rolled-out state: keep them
        states, _ = self._rollout.rollout(
            m, d, state0[None], controls[None], control_spec=mujoco.mjtState.mjSTATE_CTRL
        )
        states = states[0]
        d.ctrl[:] = controls[-1]
        d.mocap_pos[:], d.mocap_quat[:] = mocap
        qpos = states[:, 1 : 1 + m.nq]
        qvel = states[:, 1 + m.nq : 1 + m.nq + m.nv]
        expected_time = state0[0] + m.opt.timestep * np.arange(1, k + 1)
        good = np.abs(states[:, 0] - expected_time) < 0.5 * m.opt.timestep
        good &= np.all(np.isfinite(states), axis=1)
        good &= self.in_bounds(qpos)
        finite = k if good.all() else int(np.argmin(good))
        if finite < k:
            self.data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number += 1
        return qpos, qvel, finite

    def in_bounds(self, qpos: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Whether every cable node of each configuration (K, nq) lies within 50 m of the origin, (K,).

        The chain's nodes are within a cable length of its TCP (rigid links), so its TCPs alone are checked,
        which spares the batched forward kinematics of every step.
        """
        if self._is_chain:
            tcp = self._tcp_home + qpos[:, self._tcp_qpos]
            return np.abs(tcp).max(axis=(1, 2)) < 50.0 - self.config.cable.length_m
        return np.abs(self.nodes_from_qpos(qpos)).max(axis=(1, 2)) < 50.0

    def nodes_from_qpos(self, qpos: ArrayLike) -> NDArray[np.float64]:
        """Cable node positions for a batch of configurations, (K, nq) -> (K, N, 3)."""
        q = np.asarray(qpos, dtype=float)
        if self._chain is not None:
            return self._chain.nodes(q)
        return (self._node_offset + (q @ self._node_jacobian).reshape(q.shape[0], self._vert_num, 3))

    @property
    def tcp_indices(self) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
        """Where the TCPs are: their joints' qpos and dof addresses and their servos' actuator ids, each
        (n_g, 3) (x, y, z per gripper)."""
        return self._tcp_qpos.copy(), self._tcp_dof.copy(), self._tcp_act.copy()

    @property
    def chain(self) -> chain_model.ChainKinematics | None:
        """The chain cable's batched kinematics (None for the rod)."""
        return self._chain

    def reset_state(self) -> NDArray[np.float64]:
        """The integration state (``mjSTATE_INTEGRATION``) :meth:`reset` puts the scene in, as one row."""
        self.reset()
        return self.state()

    def state(self) -> NDArray[np.float64]:
        """The scene's integration state now (``mjSTATE_INTEGRATION``: time, positions, velocities, warm
        start, controls, mocap bodies), as one row."""
        state = np.empty(mujoco.mj_stateSize(self.model, self._state_spec))
        mujoco.mj_getState(self.model, self.data, state, self._state_spec)
        return state

    def load_state(self, state: NDArray[np.float64]) -> None:
        """Put the scene in an integration state (a row of :meth:`reset_state`'s kind), blow-up count 0."""
        mujoco.mj_setState(self.model, self.data, state, self._state_spec)
        self.data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number = 0

    def tcp_from_state(
        self, qpos: ArrayLike, qvel: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """TCP positions and velocities for a batch of states, each (K, n_g, 3)."""
        q, v = np.asarray(qpos), np.asarray(qvel)
        return self._tcp_home + q[:, self._tcp_qpos], v[:, self._tcp_dof]

    def push_cable(self, node: int, impulse_n_s: ArrayLike) -> None:
        """Give cable node ``node`` (1 .. N-1; 0 is held) an impulse (N s, world frame), now.

        The velocity change is the rigid-body response, ``qvel += M^-1 J^T impulse`` with ``J`` the node's
        translational Jacobian: momentum is conserved, and the node's own velocity changes by the impulse
        over its effective mass. Chain cable only (a push on a rod vertex is not implemented).

        Raises:
            ValueError: A rod cable, a node out of range, or an impulse that is not 3 finite numbers.
        """
        if self._chain is None:
            raise ValueError("push_cable needs the chain cable (cable='chain')")
        n = self._chain.num_nodes
        if isinstance(node, bool) or not isinstance(node, int | np.integer) or not 1 <= node < n:
            raise ValueError(f"node must be a cable node index 1..{n - 1} (0 is held), got {node!r}")
        impulse = np.asarray(impulse_n_s, dtype=float)
        if impulse.shape != (3,) or not np.all(np.isfinite(impulse)):
            raise ValueError(f"impulse must be 3 finite numbers (N s), got {impulse_n_s!r}")
        m, d = self.model, self.data
        mujoco.mj_forward(m, d)  # the mass matrix and body frames of the current qpos
        bodies = self._chain.bodies
        body = int(bodies[min(node, len(bodies) - 1)])
        jacp = np.zeros((3, m.nv))
        mujoco.mj_jac(m, d, jacp, None, self.cable_nodes()[node], body)
        dq = np.zeros((1, m.nv))
        mujoco.mj_solveM(m, d, dq, (jacp.T @ impulse)[None])
        d.qvel += dq[0]

    def step(self, nsteps: int = 1) -> None:
        """Advance the physics by ``nsteps`` steps with the current references."""
        mujoco.mj_step(self.model, self.data, nsteps)

    def is_finite(self) -> bool:
        """Whether the simulation has stayed sane since the last reset (blow-up check).

        MuJoCo resets the state by itself when accelerations become NaN or huge, and counts a warning; a
        blow-up is therefore detected from that counter as well as from the state.
        """
        bad = self.data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number
        finite = bool(np.all(np.isfinite(self.data.qpos)))
        return bool(bad == 0 and finite and np.abs(self.cable_nodes()).max() < 50.0)
