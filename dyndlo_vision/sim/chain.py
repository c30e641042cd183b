"""The paper's cable discretisation: a chain of capsule bodies joined by ball joints (section III-A).

``CableParams(model="chain")`` builds the cable as ``num_segments`` rigid capsules nested under the first
TCP. The first capsule is welded to the TCP (the clamped first edge, like the rod's two pinned nodes); each
of the others hangs from its predecessor on a ball joint at its start. Edges are rigid bodies, so the chain is
inextensible by construction (no edge constraints).

Elasticity per joint (discrete elastic rod energy with Voronoi length = segment length ``l``):

* bending stiffness ``EI / l`` and torsional stiffness ``GJ / l`` (``J = 2 I`` for a circular section, so
  ``GJ = EI / (1 + nu)``). MuJoCo's ball-joint spring is isotropic (torque ``-k * axis-angle``); the joint
  gets ``k = EI / l`` and one bias-only actuator per joint on its twist axis (the capsule's own axis, gear
  ``0 0 1`` in the child frame) adds ``+(EI - GJ) / l`` times the twist angle, so the net twist stiffness is
  ``GJ / l``. The actuator has no gain: its control is ignored.
* damping on all three DOFs of a joint: ``k (damping_s w + damping_quadratic_s2 w |w|)`` with ``k = EI / l``
  (linear Rayleigh plus a quadratic, drag-like term; MuJoCo's joint damping polynomial, which every
  integrator treats implicitly). The quadratic term is what keeps a 1 ms step stable when random actions
  whip the cable's tip at tens of m/s (docs/CHAIN.md).

Integrator: the scenes' default, ``discrete`` at 1 ms (implicit in the joint springs, so the stiff twist DOFs,
about 1000 rad/s, need no armature). ``implicitfast`` is barely faster per step but diverges far more often
under random actions (docs/results.md, "Simulation"). The scene uses the dense constraint Jacobian for the
chain (``PhysicsOptions.jacobian``; the same physics, faster).

Capsules collide with the floor and the props but not with each other (contype 2, conaffinity 1; the props
have MuJoCo's default 1/1).

Nodes: the joint positions plus the free end, from the held end to the far end (``num_segments + 1``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import mujoco
import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.sim.cable import CableParams

CABLE_CONTYPE = 2
CABLE_CONAFFINITY = 1


def body_name(prefix: str, index: int) -> str:
    """Name of capsule ``index`` (0 = the one welded to the TCP)."""
    return f"{prefix}_{index}"


def joint_name(prefix: str, index: int) -> str:
    """Name of the ball joint at the start of capsule ``index`` (1 .. num_segments - 1)."""
    return f"{prefix}_ball_{index}"


def geom_prefix(prefix: str) -> str:
    """What every capsule geom's name starts with (and no other geom's in our scenes)."""
    return f"{prefix}_geom_"


def geom_name(prefix: str, index: int) -> str:
    """Name of capsule ``index``'s geom."""
    return f"{geom_prefix(prefix)}{index}"


def twist_actuator_name(prefix: str, index: int) -> str:
    """Name of the twist-stiffness correction actuator of joint ``index``."""
    return f"{prefix}_twist_{index}"


def _fmt(values: Sequence[float]) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


def chain_bodies_mjcf(cable: CableParams, prefix: str, quat: Sequence[float], indent: str = "      ") -> str:
    """MJCF of the nested capsule bodies, to be placed inside the first TCP's body.

    Args:
        cable: Cable parameters (``model="chain"``).
        prefix: Name prefix of bodies, joints and geoms.
        quat: Orientation of the first capsule in the TCP frame (its local z axis is the cable direction).
    """
    seg = cable.segment_length_m
    mass = cable.mass_kg / cable.num_segments
    k_bend = cable.bending_stiffness_nm2 / seg
    damping = f"{cable.damping_s * k_bend:.9g}"
    if cable.damping_quadratic_s2 > 0:
        damping += f" {cable.damping_quadratic_s2 * k_bend:.9g}"
    geom = (
        f'type="capsule" fromto="0 0 0 0 0 {seg:.17g}" size="{cable.radius_m:.9g}" mass="{mass:.9g}" '
        f'rgba="{_fmt(cable.rgba)}" contype="{CABLE_CONTYPE}" conaffinity="{CABLE_CONAFFINITY}" condim="3" '
        f'friction="0.6" solref="0.005 1"'
    )
    opening = []
    for i in range(cable.num_segments):
        pad = indent + "  " * i
        if i == 0:
            head = f'{pad}<body name="{body_name(prefix, 0)}" quat="{_fmt(quat)}">'
        else:
            head = (
                f'{pad}<body name="{body_name(prefix, i)}" pos="0 0 {seg:.17g}">\n'
                f'{pad}  <joint name="{joint_name(prefix, i)}" type="ball" stiffness="{k_bend:.9g}" '
                f'damping="{damping}"/>'
            )
        opening.append(f"{head}\n{pad}  <geom name=\"{geom_name(prefix, i)}\" {geom}/>")
    closing = [indent + "  " * i + "</body>" for i in reversed(range(cable.num_segments))]
    return "\n" + "\n".join(opening) + "\n" + "\n".join(closing)


def chain_actuators_mjcf(cable: CableParams, prefix: str) -> str:
    """Bias-only actuators that lower each joint's twist stiffness from ``EI / l`` to ``GJ / l``."""
    seg = cable.segment_length_m
    excess = (cable.bending_stiffness_nm2 - cable.torsional_stiffness_nm2) / seg
    if excess <= 0:
        return ""
    return "".join(
        f'\n    <general name="{twist_actuator_name(prefix, i)}" joint="{joint_name(prefix, i)}" '
        f'gear="0 0 1" '
        f'gainprm="0" biastype="affine" biasprm="0 {excess:.9g} 0"/>'
        for i in range(1, cable.num_segments)
    )


# Right multiplication by q as a 4x4 matrix acting on p: p (x) q = _RIGHT(q) p, for (w, x, y, z) quaternions.
_RIGHT_INDEX = np.array([[0, 1, 2, 3], [1, 0, 3, 2], [2, 3, 0, 1], [3, 2, 1, 0]])
_RIGHT_SIGN = np.array([[1, -1, -1, -1], [1, 1, 1, -1], [1, -1, 1, 1], [1, 1, -1, 1]], dtype=float)


def _z_axes(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Third column of the rotation matrix of unit quaternions (..., 4) -> (..., 3)."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=-1)


class ChainKinematics:
    """Cable node positions of a chain scene as a function of ``qpos`` (batched forward kinematics)."""

    #: Batches up to this size go through ``mj_kinematics`` on a scratch ``MjData`` (faster for few rows).
    SMALL_BATCH = 8

    def __init__(self, model: mujoco.MjModel, prefix: str, num_segments: int, segment_length_m: float,
                 tcp_body: str) -> None:
        self.model = model
        self._scratch = mujoco.MjData(model)
        self._bodies = np.array([model.body(body_name(prefix, i)).id for i in range(num_segments)])
        # The compiled segment length (the MJCF carries 9 significant digits of segment_length_m).
        compiled = np.array([0.0, 0.0, segment_length_m])
        if num_segments > 1:
            compiled = model.body_pos[self._bodies[1]]
        if not np.allclose(compiled, [0.0, 0.0, segment_length_m], rtol=1e-8, atol=0.0):
            raise RuntimeError("each capsule must start at its parent's end, in its parent's orientation")
        self._end_local = compiled.copy()
        tcp = model.body(tcp_body)
        if model.body_parentid[tcp.id] != 0 or np.any(model.body_quat[tcp.id] != [1, 0, 0, 0]):
            raise RuntimeError("the chain's TCP must be a world child with identity orientation")
        self._tcp_pos = model.body_pos[tcp.id].copy()
        jnts = range(model.body_jntadr[tcp.id], model.body_jntadr[tcp.id] + model.body_jntnum[tcp.id])
        for j in jnts:
            if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_SLIDE:
                raise RuntimeError("the chain's TCP must move on slide joints only")
        self._tcp_slides = [(int(model.jnt_qposadr[j]), model.jnt_axis[j].copy()) for j in jnts]
        self._ball_qpos: list[int] = []
        for i, b in enumerate(self._bodies):
            if int(model.body_parentid[b]) != (tcp.id if i == 0 else self._bodies[i - 1]):
                raise RuntimeError("the chain's capsules must be nested in order under the TCP")
            if i == 0:
                if model.body_jntnum[b] != 0 or np.any(model.body_pos[b] != 0):
                    raise RuntimeError("the first capsule must be welded to the TCP at its origin")
                continue
            j = model.body_jntadr[b]
            if model.body_jntnum[b] != 1 or model.jnt_type[j] != mujoco.mjtJoint.mjJNT_BALL:
                raise RuntimeError(f"capsule {i} must have exactly one ball joint")
            if np.any(model.jnt_pos[j] != 0):
                raise RuntimeError("ball joints must sit at their capsule's origin")
            if (not np.allclose(model.body_pos[b], self._end_local, rtol=0, atol=1e-12)
                    or np.any(model.body_quat[b] != [1, 0, 0, 0])):
                raise RuntimeError("each capsule must start at its parent's end, in its parent's orientation")
            self._ball_qpos.append(int(model.jnt_qposadr[j]))
        self._first_quat = model.body_quat[self._bodies[0]].copy()  # the TCP does not rotate
        self._ball_index = (np.array(self._ball_qpos)[:, None] + np.arange(4)).ravel()

    @property
    def num_nodes(self) -> int:
        return len(self._bodies) + 1

    @property
    def bodies(self) -> NDArray[np.int64]:
        """Body ids of the capsules, held end first (node ``i < N - 1`` is capsule ``i``'s origin)."""
        return self._bodies.copy()

    def nodes(self, qpos: NDArray[np.float64]) -> NDArray[np.float64]:
        """Node positions for a batch of configurations, (K, nq) -> (K, N + 1, 3)."""
        q = np.asarray(qpos, dtype=float)
        if q.shape[0] <= self.SMALL_BATCH:
            return self._nodes_mj(q)
        return self._nodes_np(q)

    def _nodes_mj(self, q: NDArray[np.float64]) -> NDArray[np.float64]:
        m, d = self.model, self._scratch
        out = np.empty((q.shape[0], self.num_nodes, 3))
        for k in range(q.shape[0]):
            d.qpos[:] = q[k]
            mujoco.mj_kinematics(m, d)
            out[k, :-1] = d.xpos[self._bodies]
            last = self._bodies[-1]
            out[k, -1] = d.xpos[last] + d.xmat[last].reshape(3, 3) @ self._end_local
        return out

    def nodes_vectorized(
        self, q: NDArray[np.float64], segment_m: NDArray[np.float64] | None = None
    ) -> NDArray[np.float64]:
        """Node positions computed with NumPy for every row at once (what :meth:`nodes` does for more than
        :attr:`SMALL_BATCH` rows), (K, nq) -> (K, N + 1, 3).

        ``segment_m`` (K,) gives each row its own compiled segment length, for chains of other lengths but the
        same structure (the batched environment's random cables); None: this chain's. Each row's result is
        independent of the other rows.
        """
        return self._nodes_np(np.asarray(q, dtype=float), segment_m)

    def segment_m(self) -> float:
        """The compiled segment length (what :meth:`nodes_vectorized` takes per row)."""
        return float(self._end_local[2])

    def _nodes_np(self, q: NDArray[np.float64], segment_m: NDArray[np.float64] | None = None
                  ) -> NDArray[np.float64]:
        k = q.shape[0]
        tcp = np.tile(self._tcp_pos, (k, 1))
        for adr, axis in self._tcp_slides:
            tcp = tcp + q[:, adr, None] * axis
        balls = q[:, self._ball_index].reshape(k, -1, 4)
        right = balls[..., _RIGHT_INDEX] * _RIGHT_SIGN  # (K, N - 1, 4, 4)
        rots = np.empty((k, len(self._bodies), 4))
        rots[:, 0] = self._first_quat
        for i in range(1, len(self._bodies)):
            rots[:, i] = np.matmul(right[:, i - 1], rots[:, i - 1, :, None])[..., 0]
        seg = self._end_local[2] if segment_m is None else np.asarray(segment_m, dtype=float)[:, None, None]
        edges = seg * _z_axes(rots)  # (K, N, 3)
        out = np.empty((k, self.num_nodes, 3))
        out[:, 0] = tcp
        np.cumsum(edges, axis=1, out=out[:, 1:])
        out[:, 1:] += tcp[:, None]
        return out

    def check(self, rng: np.random.Generator) -> float:
        """Largest difference between the NumPy and MuJoCo kinematics at random configurations."""
        m = self.model
        q = np.tile(m.qpos0, (self.SMALL_BATCH + 1, 1))
        for a in self._ball_qpos:
            if a >= 0:
                quat = rng.normal(size=(q.shape[0], 4))
                q[:, a:a + 4] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        for adr, _ in self._tcp_slides:
            q[:, adr] = rng.normal(0.0, 0.3, q.shape[0])
        return float(np.abs(self._nodes_np(q) - self._nodes_mj(q)).max())


def walk_polyline(path: NDArray[np.float64], start: NDArray[np.float64], start_segment: int,
                  step: float, count: int) -> NDArray[np.float64]:
    """Points along a polyline at chord distance ``step`` from each other, walking forward from ``start``.

    ``start`` lies on segment ``start_segment`` of ``path``. Each next point is the first point further along
    the polyline at distance ``step`` from the previous one, so a chain of rigid links of length ``step``
    follows the path; past its end, the last segment's direction is extended.

    Returns:
        (count, 3) points, not including ``start``.
    """
    pts = np.asarray(path, dtype=float)
    d = pts[-1] - pts[-2]
    pts = np.vstack([pts, pts[-1] + d / np.linalg.norm(d) * (step * (count + 1))])
    out = np.empty((count, 3))
    p = np.asarray(start, dtype=float)
    seg, t_min = start_segment, _param_on_segment(pts, start_segment, p)
    for n in range(count):
        while True:
            t = _sphere_exit(pts[seg], pts[seg + 1], p, step, t_min)
            if t is not None:
                break
            seg += 1
            t_min = 0.0
        p = pts[seg] + t * (pts[seg + 1] - pts[seg])
        t_min = t
        out[n] = p
    return out


def _param_on_segment(pts: NDArray[np.float64], seg: int, p: NDArray[np.float64]) -> float:
    a, b = pts[seg], pts[seg + 1]
    ab = b - a
    return float(np.clip(np.dot(p - a, ab) / np.dot(ab, ab), 0.0, 1.0))


def _sphere_exit(a: NDArray[np.float64], b: NDArray[np.float64], centre: NDArray[np.float64], radius: float,
                 t_min: float) -> float | None:
    """The larger ``t`` in ``[t_min, 1]`` with ``|a + t (b - a) - centre| = radius``, else None."""
    d = b - a
    f = a - centre
    qa = float(d @ d)
    qb = 2.0 * float(f @ d)
    qc = float(f @ f) - radius * radius
    disc = qb * qb - 4 * qa * qc
    if qa <= 0 or disc < 0:
        return None
    t = (-qb + math.sqrt(disc)) / (2 * qa)
    if t < t_min - 1e-12 or t > 1.0 + 1e-12:
        return None
    return t


def ball_quats_along(nodes: NDArray[np.float64], first_rotation: NDArray[np.float64]) -> NDArray[np.float64]:
    """Ball-joint quaternions that put the capsules along ``nodes`` without twist.

    Args:
        nodes: (N + 1, 3) node positions; the first capsule (from node 0 to node 1) is clamped and keeps
            ``first_rotation`` (its world orientation, a quaternion).

    Returns:
        (N - 1, 4) relative quaternions of joints 1 .. N - 1: each is the minimal rotation taking the
        previous capsule's axis onto the next edge's direction (parallel transport: no twist).
    """
    rot = np.asarray(first_rotation, dtype=float)
    quats = []
    for i in range(1, len(nodes) - 1):
        d = nodes[i + 1] - nodes[i]
        d = d / np.linalg.norm(d)
        neg = np.array([rot[0], -rot[1], -rot[2], -rot[3]])
        local = np.zeros(3)
        mujoco.mju_rotVecQuat(local, d, neg)
        q = np.zeros(4)
        mujoco.mju_quatZ2Vec(q, local)
        quats.append(q)
        new = np.zeros(4)
        mujoco.mju_mulQuat(new, rot, q)
        rot = new / np.linalg.norm(new)
    return np.array(quats).reshape(-1, 4)
