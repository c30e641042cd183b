"""How well ClockSync puts time.monotonic() on a robot driver's clock, against the fake EGM controller.

The fake controller (``robots.FakeEgmController``) streams joint states over UDP on loopback with its
own clock (seconds since it started), as a real ABB controller does; the driver (``EgmRobot``) reports that
clock in ``state().t``. Every 40 ms (the loop's period) this reads the state and ``time.monotonic()``
and feeds the pair to a ``ClockSync``, as ``TrackedState`` does. It prints the gap between the clocks, the
spread of the raw pairs (the state's age at reading: what a single pair would be off by), the estimate's
error, and how much the estimate moves once it has a second of pairs. The fake sends the state of its time
``t`` at ``time.monotonic() = origin + t`` (not earlier; later when its thread is late), so the true offset
is ``-origin``, read from the fake.

    python benchmarks/clock_sync.py [--seconds 5]
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np

from dyndlo_vision.control.clocks import ClockSync
from dyndlo_vision.robots import EgmRobot, FakeEgmController
from dyndlo_vision.robots.kinematics import ArmKinematics, abb_gofa_crb15000

PERIOD_S = 0.04


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="how long to read pairs (default 5)")
    parser.add_argument("--quick", action="store_true", help="read pairs for 1.5 s")
    args = parser.parse_args()
    if args.quick:
        args.seconds = 1.5
    if not args.seconds > 1.0:
        parser.error(f"--seconds must be > 1, got {args.seconds}")
    kin = ArmKinematics(abb_gofa_crb15000())
    robot = EgmRobot(kin, port=0, answer_timeout_s=5.0, connect_timeout_s=5.0)
    q_home = kin.ik((0.4, 0.0, 0.5)).q
    fake = FakeEgmController(kin.arm, q_home, ("127.0.0.1", robot.bind()), reply_timeout_s=2.0)
    fake.start()
    sync = ClockSync()
    raw, estimates = [], []
    try:
        robot.connect()
        for _ in range(int(args.seconds / PERIOD_S)):
            robot_t, local_t = robot.state().t, time.monotonic()
            sync.observe(robot_t, local_t)
            raw.append(robot_t - local_t)
            estimates.append(sync.offset_s)
            time.sleep(PERIOD_S)
    finally:
        robot.close()
        fake.close()
    r, e = np.array(raw), np.array(estimates)
    one_s = int(1.0 / PERIOD_S)
    print(json.dumps({
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "pairs": len(r),
        "robot_clock_minus_monotonic_s": round(float(e[-1]), 6),
        "raw_pair_spread_ms": round(1e3 * float(r.max() - r.min()), 3),
        "raw_pair_median_below_estimate_ms": round(1e3 * float(e[-1] - np.median(r)), 3),
        "estimate_below_true_offset_ms": round(1e3 * float(-fake.clock_origin - e[-1]), 3),
        "estimate_change_after_1s_ms": round(1e3 * float(e[-1] - e[one_s]), 3),
    }, indent=1))


if __name__ == "__main__":
    main()
