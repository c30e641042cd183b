"""Solver settings for the cable scenes."""

from __future__ import annotations

from dataclasses import dataclass

_INTEGRATORS = ("discrete", "Euler", "RK4", "implicitfast", "implicit")
#: Integrators MuJoCo 4 accepts for 1D rod (flex) elasticity; the chain cable takes every integrator.
ROD_INTEGRATORS = ("discrete", "Euler", "RK4")
_SOLVERS = ("Newton", "CG")
_JACOBIANS = ("dense", "sparse", "auto")


@dataclass(frozen=True)
class PhysicsOptions:
    """MuJoCo ``<option>`` values used by every scene.

    Default: ``discrete`` + Newton at 1 ms. ``Euler`` is faster and closer to a fine reference on smooth
    whips, but diverges under random actions (the per-edge twist joints are stiff and light), while
    ``discrete`` does not (docs/results.md, "Simulation"); an RL sandbox explores with random actions, so
    robustness wins.

    Rod elasticity in MuJoCo 4 runs under ``discrete`` (implicit in the effective metric), ``Euler`` or
    ``RK4`` (explicit); ``implicit``/``implicitfast`` are rejected by MuJoCo for rods (and by
    :class:`~dyndlo_vision.sim.SceneConfig`). The chain cable (``CableParams(model="chain")``) takes them all.

    Attributes:
        timestep_s: Physics step.
        integrator: ``"discrete"``, ``"Euler"``, ``"RK4"``, ``"implicitfast"`` or ``"implicit"`` (the last two
            for the chain cable only).
        solver: ``"Newton"`` or ``"CG"`` (PGS does not support flexes).
        iterations: Maximum constraint-solver iterations.
        tolerance: Solver early-termination tolerance.
        twist_armature_kg_m2: Armature (added rotational inertia) of the rod's per-edge twist hinges, or of
            the chain's twist DOFs (the third DOF of each ball joint, about the capsule's axis). MuJoCo
            gives them bodies of 1e-9 kg m^2, stiff in torsion: the explicit integrators diverge on them.
            1e-8 stops that and leaves planar motion unchanged (docs/results.md, "Decided questions").
            0 (default): MuJoCo's own.
        jacobian: Constraint Jacobian storage, ``"dense"``, ``"sparse"`` or ``"auto"`` (MuJoCo's: dense below
            60 DOFs). None (default): ``"dense"`` for the chain cable (the same physics, faster in every task
            scene, where the chain's 60 to 180 DOFs make ``auto`` pick sparse: docs/CHAIN.md), ``"auto"`` for
            the rod.
    """

    timestep_s: float = 0.001
    integrator: str = "discrete"
    solver: str = "Newton"
    iterations: int = 50
    tolerance: float = 1e-8
    twist_armature_kg_m2: float = 0.0
    jacobian: str | None = None

    def __post_init__(self) -> None:
        if self.jacobian is not None and self.jacobian not in _JACOBIANS:
            raise ValueError(f"jacobian={self.jacobian!r}; expected one of {_JACOBIANS} or None")
        if self.integrator not in _INTEGRATORS:
            raise ValueError(
                f"integrator={self.integrator!r} is not supported; expected one of {_INTEGRATORS}"
            )
        if self.solver not in _SOLVERS:
            raise ValueError(f"solver={self.solver!r}; expected one of {_SOLVERS}")
        if not 1e-5 <= self.timestep_s <= 0.01:
            raise ValueError(f"timestep_s={self.timestep_s} is outside [1e-5, 0.01] s")
        if self.iterations < 1:
            raise ValueError(f"iterations={self.iterations} must be >= 1")
        if not 0.0 <= self.twist_armature_kg_m2 <= 1e-3:
            raise ValueError(f"twist_armature_kg_m2={self.twist_armature_kg_m2} is outside [0, 1e-3] kg m^2")

    def to_mjcf(self, cable_model: str = "rod") -> str:
        """Return the ``<option .../>`` attributes as an MJCF string (for a cable of ``cable_model``)."""
        jacobian = self.jacobian or ("dense" if cable_model == "chain" else "auto")
        return (
            f'timestep="{self.timestep_s}" integrator="{self.integrator}" solver="{self.solver}" '
            f'iterations="{self.iterations}" ls_iterations="{max(5, self.iterations // 2)}" '
            f'tolerance="{self.tolerance}" jacobian="{jacobian}"'
        )
