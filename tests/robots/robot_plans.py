"""What the robot-driver tests share: tip-control plans as setpoints, and sending one from the fake's now."""

from __future__ import annotations

from typing import Any

import numpy as np

from dyndlo_vision.robots.protocol import Setpoints
from dyndlo_vision.tasks.tip_control import TCP_HOME_M, TipControl
from dyndlo_vision.trajectory import BSplineTrajectory

# A gentle multi-point tip-control action (normalised): +5 cm in x per point, z down-flat-up, 0.45 s apart.
GENTLE_ACTION = np.array([0.2, -0.2, 0.2, 0.0, 0.2, 0.2, 0.75, 0.75, 0.75])
# The same action space at its extremes: 25 cm jumps 0.1 s apart, far beyond an arm's joint accelerations.
VIOLENT_ACTION = np.array([1.0, -1.0, -1.0, 1.0, 1.0, -1.0, -1.0, -1.0, -1.0])
TIMEOUT_S = 30.0  # generous: only reached when something is broken


def tip_control_setpoints(
    action: np.ndarray, t0: float, rate_hz: float = 100.0
) -> tuple[Setpoints, np.ndarray]:
    """Setpoints of the tip-control plan for ``action`` from the TCP home at time t0, and the plan's end."""
    points, times = TipControl(planar=True).action_spec().decode(action, TCP_HOME_M, t0)
    plan = BSplineTrajectory(points, times)
    t = np.arange(times[0], times[-1] + 1e-9, 1.0 / rate_hz)
    t[-1] = times[-1]
    position, velocity = plan.position(t), plan.velocity(t)
    return Setpoints(t=t, position=position[:, None, :], velocity=velocity[:, None, :]), points[-1]


def send_from_now(robot: Any, fake: Any, action: np.ndarray) -> tuple[Setpoints, np.ndarray]:
    """Plan ``action`` from the robot's commanded time + 20 ms and send it; returns setpoints and plan end.

    The fake controller's clock is held while planning and checking, so the plan cannot start in the past.
    """
    fake.hang()
    try:
        setpoints, end = tip_control_setpoints(action, robot.commanded_state().t + 0.02)
        robot.send(setpoints)
    finally:
        fake.resume()
    return setpoints, end
