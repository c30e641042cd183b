"""A late correction that a student applies whole when its observation says it is due: a gate.

Why: the vaulting expert corrects its plan at one decision (the late commitment, K = 8) for about one cable in
seven, by a multiple of one direction (``distill --search-candidates line:N``). A student fitted by least
squares to those labels, unsure from its noisy observation *whether* a cable needs the correction, outputs
about P(correct) x length, which is a sixth of the correction that vaults and does not vault
(docs/RESULTS.md, session 30). The gate separates the two questions: a logistic classifier on the student's
own input at decision K says whether to correct, and the correction, when made, has its full length.

:class:`CorrectionGate` is pure computation (numpy); :class:`GatedPolicy` is the student with its gate, as
:func:`dyndlo_vision.policies.load` returns it for a policy whose metadata has ``correction_gate``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class CorrectionGate:
    """At decision ``decision``: add ``length * direction`` to the student's action when the logistic
    ``sigmoid(weights . (x - mean) / scale + bias)`` of its input ``x`` is at least ``threshold``.

    Args:
        decision: K, the decision (0 first) at which the gate is asked.
        direction: Unit vector in the normalised action space (the action's size).
        length: The correction's length along ``direction`` (normalised action units; signed).
        mean, scale: Standardisation of the student's input (its size; ``scale`` positive).
        weights, bias: The logistic classifier on the standardised input.
        threshold: The probability from which the correction is made, in (0, 1).
    """

    decision: int
    direction: tuple[float, ...]
    length: float
    mean: tuple[float, ...]
    scale: tuple[float, ...]
    weights: tuple[float, ...]
    bias: float
    threshold: float = 0.5

    def __post_init__(self) -> None:
        if isinstance(self.decision, bool) or not isinstance(self.decision, int) or self.decision < 0:
            raise ValueError(f"gate decision {self.decision!r}; expected a decision index >= 0")
        direction = np.asarray(self.direction, dtype=np.float64)
        if direction.ndim != 1 or direction.size == 0 or abs(np.linalg.norm(direction) - 1.0) > 1e-6:
            norm = np.linalg.norm(direction)
            raise ValueError(f"gate direction must be a unit vector, got norm {norm:.6g}")
        sizes = {name: len(getattr(self, name)) for name in ("mean", "scale", "weights")}
        if len(set(sizes.values())) != 1:
            raise ValueError(f"gate mean, scale and weights must have one size (the student's input), "
                             f"got {sizes}")
        if not all(s > 0 and math.isfinite(s) for s in self.scale):
            raise ValueError("gate scale must be positive and finite")
        if not (0.0 < self.threshold < 1.0):
            raise ValueError(f"gate threshold {self.threshold!r}; expected a probability in (0, 1)")
        if not (math.isfinite(self.length) and math.isfinite(self.bias)
                and all(math.isfinite(v) for v in (*self.mean, *self.weights))):
            raise ValueError("gate length, bias, mean and weights must be finite")

    @property
    def input_size(self) -> int:
        """Values in the student's input (table II plus its features)."""
        return len(self.weights)

    def probability(self, student_input: NDArray[np.floating[Any]]) -> float:
        """The classifier's probability that the correction is due, for one student input."""
        x = np.asarray(student_input, dtype=np.float64)
        if x.shape != (self.input_size,):
            raise ValueError(f"gate expects one student input of {self.input_size} values, "
                             f"got shape {x.shape}")
        z = float(np.dot(self.weights, (x - np.asarray(self.mean)) / np.asarray(self.scale)) + self.bias)
        return float(1.0 / (1.0 + math.exp(-z))) if z > -700 else 0.0

    def correction(self, student_input: NDArray[np.floating[Any]]) -> NDArray[np.float64]:
        """What to add to the student's action at decision K: ``length * direction`` or zeros."""
        due = self.probability(student_input) >= self.threshold
        return (self.length if due else 0.0) * np.asarray(self.direction, dtype=np.float64)

    def to_json(self) -> dict[str, Any]:
        """The gate as JSON-ready values (:meth:`from_json` reads them back)."""
        return {
            "decision": self.decision, "direction": list(self.direction), "length": self.length,
            "mean": list(self.mean), "scale": list(self.scale), "weights": list(self.weights),
            "bias": self.bias, "threshold": self.threshold,
        }

    @classmethod
    def from_json(cls, values: dict[str, Any]) -> CorrectionGate:
        """A gate from :meth:`to_json`'s values; missing or extra keys are refused by name."""
        fields = set(cls.__dataclass_fields__)
        given = set(values)
        if not (fields - {"threshold"}) <= given <= fields:
            raise ValueError(f"correction gate keys {sorted(given)}; expected {sorted(fields)}")
        floats = {k: tuple(float(v) for v in values[k]) for k in ("direction", "mean", "scale", "weights")}
        return cls(decision=values["decision"], length=float(values["length"]), bias=float(values["bias"]),
                   threshold=float(values.get("threshold", 0.5)), **floats)
