"""Cable (deformable linear object) parameters.

Two models of the cable (``CableParams.model``):

* ``"chain"`` (default): the paper's discretisation (section III-A), rigid capsules joined by ball joints with
  bending and torsional springs (``dyndlo_vision.sim.chain``). Inextensible by construction, and faster than
  the paper's own MuJoCo 3 model (docs/CHAIN.md).
* ``"rod"``: a MuJoCo 4 discrete elastic rod, a 1D ``flexcomp`` with ``<elasticity>`` (bending and torsion).
  Its edges are held by soft equality constraints and stretch under fast motion (up to 15 % in tip control,
  125 % in task IV at 40 ms decisions); it was the default before the chain.

Defaults follow the DynDLO paper (section III-A and V-B):
a 50 cm cable of 20 segments, 10 g, Young's modulus 2 MPa. The paper gives no radius; we take 2 mm, which
for 10 g over 50 cm gives a density of about 1.6 g/cm^3, that of a PVC-insulated cable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# Paper, section V-B: cable used on the real robot and in simulation.
PAPER_CABLE_MASS_KG = 0.010
PAPER_YOUNG_PA = 2.0e6
# Paper, section III-A: number of bodies by cable length.
PAPER_SHORT_CABLE = (0.50, 20)
PAPER_LONG_CABLE = (0.90, 60)
CABLE_MODELS = ("rod", "chain")
#: Default damping of each model (``CableParams.damping_s`` / ``damping_quadratic_s2`` left as None).
#: Chain: the quadratic term keeps a 1 ms step stable under random actions (docs/CHAIN.md).
DEFAULT_DAMPING_S = {"rod": 0.002, "chain": 0.005}
DEFAULT_DAMPING_QUADRATIC_S2 = {"rod": 0.0, "chain": 0.05}


@dataclass(frozen=True)
class CableParams:
    """Physical and discretisation parameters of one cable.

    Attributes:
        length_m: Rest length of the cable.
        num_segments: Number of rod edges or chain capsules (the cable has ``num_segments + 1`` nodes).
        mass_kg: Total mass, spread evenly over the nodes (rod) or the capsules (chain).
        radius_m: Radius of the circular cross-section (sets bending stiffness, collisions, rendering).
        young_pa: Young's modulus E.
        poisson: Poisson's ratio (sets the shear modulus used for torsion, G = E / (2 (1 + nu))).
        damping_s: Rayleigh damping coefficient of the elasticity, in seconds (chain: joint damping is
            ``damping_s`` times the joint's bending stiffness). None: the model's default
            (``DEFAULT_DAMPING_S``).
        rgba: Colour used for rendering (a saturated colour keeps the tracker's job well defined).
        model: ``"rod"`` (discrete elastic rod flex) or ``"chain"`` (capsules on ball joints).
        damping_quadratic_s2: Chain only: quadratic joint damping, in s^2. Each joint gets the damping
            torque ``-k (damping_s w + damping_quadratic_s2 w |w|)``, ``k`` its bending stiffness and ``w``
            its angular velocity. A drag-like term, small at the rates of whips within v_max, that keeps
            the chain from diverging at 1 ms when random actions whip it far beyond (docs/CHAIN.md).
            None: the model's default (``DEFAULT_DAMPING_QUADRATIC_S2``); the rod takes only 0.
    """

    length_m: float = 0.50
    num_segments: int = 20
    mass_kg: float = PAPER_CABLE_MASS_KG
    radius_m: float = 0.002
    young_pa: float = PAPER_YOUNG_PA
    poisson: float = 0.3
    damping_s: float | None = None  # resolved to a float in __post_init__
    rgba: tuple[float, float, float, float] = (0.85, 0.15, 0.1, 1.0)
    model: str = "chain"
    damping_quadratic_s2: float | None = None  # resolved to a float in __post_init__

    def __post_init__(self) -> None:
        if self.model not in CABLE_MODELS:
            raise ValueError(f"cable model={self.model!r}; expected one of {CABLE_MODELS}")
        if self.damping_s is None:
            object.__setattr__(self, "damping_s", DEFAULT_DAMPING_S[self.model])
        if self.damping_quadratic_s2 is None:
            object.__setattr__(self, "damping_quadratic_s2", DEFAULT_DAMPING_QUADRATIC_S2[self.model])
        if self.model == "rod" and self.damping_quadratic_s2 != 0:
            raise ValueError("damping_quadratic_s2 applies to the chain cable only (model='chain')")
        checks = {
            "length_m": (self.length_m, 0.05, 5.0),
            "mass_kg": (self.mass_kg, 1e-4, 2.0),
            "radius_m": (self.radius_m, 2e-4, 0.03),
            "young_pa": (self.young_pa, 1e3, 1e10),
            "damping_s": (self.damping_s, 0.0, 1.0 if self.model == "chain" else 0.1),
            "damping_quadratic_s2": (self.damping_quadratic_s2, 0.0, 1.0),
        }
        for name, (value, low, high) in checks.items():
            if not (isinstance(value, int | float) and math.isfinite(value) and low <= value <= high):
                raise ValueError(f"cable {name}={value!r} is outside the supported range [{low}, {high}]")
        if not isinstance(self.num_segments, int) or not 2 <= self.num_segments <= 200:
            raise ValueError(f"cable num_segments={self.num_segments!r} must be an int in [2, 200]")
        if not 0.0 <= self.poisson < 0.5:
            raise ValueError(f"cable poisson={self.poisson!r} must be in [0, 0.5)")
        if self.segment_length_m < 2.5 * self.radius_m:
            # Neighbouring capsules would overlap along most of their length: contacts and bending go wrong.
            raise ValueError(
                f"cable segments of {self.segment_length_m:.4f} m are too short "
                f"for radius {self.radius_m} m: "
                f"use fewer segments or a thinner cable (segment length >= 2.5 * radius)"
            )
        if len(self.rgba) != 4:
            raise ValueError(f"cable rgba={self.rgba!r} must have 4 components")

    @property
    def num_nodes(self) -> int:
        """Number of nodes (vertices) along the cable."""
        return self.num_segments + 1

    @property
    def segment_length_m(self) -> float:
        """Rest length of one edge."""
        return self.length_m / self.num_segments

    @property
    def second_moment_m4(self) -> float:
        """Second moment of area of the circular section, I = pi r^4 / 4."""
        return math.pi * self.radius_m**4 / 4.0

    @property
    def bending_stiffness_nm2(self) -> float:
        """Bending rigidity E*I."""
        return self.young_pa * self.second_moment_m4

    @property
    def shear_modulus_pa(self) -> float:
        """Shear modulus G = E / (2 (1 + nu))."""
        return self.young_pa / (2.0 * (1.0 + self.poisson))

    @property
    def torsional_stiffness_nm2(self) -> float:
        """Torsional rigidity G*J, with J = pi r^4 / 2 = 2 I for a circular section."""
        return self.shear_modulus_pa * 2.0 * self.second_moment_m4


def paper_cable(length_m: float = 0.5, **overrides: float | str) -> CableParams:
    """Return the paper's cable of the given length (0.5 m: 20 segments, 0.9 m: 60 segments)."""
    segments = {PAPER_SHORT_CABLE[0]: PAPER_SHORT_CABLE[1], PAPER_LONG_CABLE[0]: PAPER_LONG_CABLE[1]}
    if length_m not in segments:
        raise ValueError(f"the paper uses cables of 0.5 m and 0.9 m, got length_m={length_m}")
    return CableParams(length_m=length_m, num_segments=segments[length_m], **overrides)  # type: ignore[arg-type]
