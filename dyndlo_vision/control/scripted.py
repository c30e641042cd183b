"""Built-in scripted tip-control plans for ``dyndlo-vision run`` (``policy: scripted:<name>``).

They exist so that a robot set-up can be brought up end to end (calibration, driver, camera, safety, report)
with a plan every arm can follow, before a learned policy whose plans fit the arm's joint limits is shipped.
They are policies in the loop's sense (``observation -> normalised action``) and decide from the observation
alone (table II: TCP position and velocity, P_DLO, P*).

* ``slow-reach``: carry the hanging cable, slowly (three 0.5 s segments, the longest the action space
  allows), to where its tip would hang at the target: the TCP moves to P* minus the tip's hanging offset
  (P_DLO - TCP when the plan is made). When the arm cannot reach that point with the tool pointing down, the
  TCP goes as far along the straight line as the arm reaches, less 3 cm. A quasi-static move: the tip may
  hit the target only when the target is within that reach and the cable has swung out by the end.
* ``slow-reach-replan``: the same destination (decided from the first observation), as a multi-step policy:
  re-planned every 40 ms from the commanded state for 1.6 s, as the multi-step policies are. It exercises
  re-planning on a robot (every plan joins the one the arm is following) without chasing the tip estimate,
  which swings with the cable.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["SCRIPTED_POLICIES", "SlowReach", "scripted_policy"]

#: Name -> one-line description.
SCRIPTED_POLICIES: dict[str, str] = {
    "slow-reach": "carry the hanging tip slowly (3 x 0.5 s) to the target, as far as the arm reaches",
    "slow-reach-replan": "slow-reach re-planned every control period (multi-step)",
}
#: The scripted policies that re-plan every control period.
MULTI_STEP = frozenset({"slow-reach-replan"})
REACH_MARGIN_M = 0.03


def _normalise(value: NDArray[np.float64], span: tuple[float, float]) -> NDArray[np.float64]:
    lo, hi = span
    return np.clip(2.0 * (value - lo) / (hi - lo) - 1.0, -1.0, 1.0)


class SlowReach:
    """The ``slow-reach`` plan (see the module docstring).

    Args:
        spec: The task's action spec (planar tip control: ``num_points`` x (dx, dz), then the segment times).
        reachable: ``tcp position (3,) -> bool``, whether the arm reaches it (None: everything is).
        keep_destination: Decide the destination at the first call and keep it (``slow-reach-replan``).
    """

    def __init__(self, spec: Any, reachable: Callable[[NDArray[np.float64]], bool] | None = None,
                 keep_destination: bool = False) -> None:
        if not spec.planar:
            raise ValueError("scripted:slow-reach plans planar tip control only")
        self.spec = spec
        self.reachable = reachable
        self.keep_destination = keep_destination
        self._kept: NDArray[np.float64] | None = None

    def destination(self, obs: NDArray[np.float64]) -> NDArray[np.float64]:
        """Where the TCP goes for this observation."""
        obs = np.asarray(obs, dtype=float)
        tcp, p_dlo, goal = obs[0:3], obs[6:9], obs[9:12]
        hang = p_dlo - tcp if np.all(np.isfinite(p_dlo)) else np.zeros(3)
        want = goal - hang
        want[1] = tcp[1]  # planar: the plane the TCP is in
        n = self.spec.num_points
        # Each segment moves at most the action's step range.
        lo = np.array([self.spec.dx_m[0], 0.0, self.spec.dz_m[0]]) * n
        hi = np.array([self.spec.dx_m[1], 0.0, self.spec.dz_m[1]]) * n
        want = tcp + np.clip(want - tcp, lo, hi)
        if self.reachable is None or self.reachable(want):
            return want
        reach, miss = 0.0, 1.0  # bisection along the line: the TCP itself is reachable
        for _ in range(30):
            mid = 0.5 * (reach + miss)
            if self.reachable(tcp + mid * (want - tcp)):
                reach = mid
            else:
                miss = mid
        length = float(np.linalg.norm(want - tcp))
        s = max(0.0, reach - REACH_MARGIN_M / length) if length > 0 else 0.0
        return tcp + s * (want - tcp)

    def __call__(self, obs: NDArray[np.float64]) -> NDArray[np.float32]:
        obs = np.asarray(obs, dtype=float)
        if not self.keep_destination:
            dest = self.destination(obs)
        else:
            if self._kept is None:
                self._kept = self.destination(obs)
            dest = self._kept
        step = (dest - obs[0:3]) / self.spec.num_points
        n = self.spec.num_points
        action = np.empty(3 * n)
        action[0:2 * n:2] = _normalise(np.full(n, step[0]), self.spec.dx_m)
        action[1:2 * n:2] = _normalise(np.full(n, step[2]), self.spec.dz_m)
        action[2 * n:] = 1.0  # the longest segment time
        return action.astype(np.float32)


def scripted_policy(name: str, spec: Any, reachable: Callable[[NDArray[np.float64]], bool] | None = None
                    ) -> Callable[[NDArray[np.float64]], NDArray[np.float32]]:
    """The scripted policy ``name`` (a key of :data:`SCRIPTED_POLICIES`).

    Raises:
        ValueError: An unknown name.
    """
    if name not in SCRIPTED_POLICIES:
        raise ValueError(f"unknown scripted policy {name!r}; expected one of {sorted(SCRIPTED_POLICIES)}")
    return SlowReach(spec, reachable, keep_destination=name in MULTI_STEP)
