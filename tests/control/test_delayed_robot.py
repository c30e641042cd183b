"""Actuation latency (issue 16's optional disturbance): every setpoint executed a fixed time after its own."""

from __future__ import annotations

import json

import numpy as np
import pytest

import dyndlo_vision  # noqa: F401
from dyndlo_vision.cli import main
from dyndlo_vision.control.sim_robot import DelayedRobot
from dyndlo_vision.robots.protocol import Setpoints

DT = 0.002


class Recorder:
    """Stands in for SimRobot: keeps what it was told to execute."""

    def __init__(self) -> None:
        self.sent: list[Setpoints] = []
        self.connected = False

    def send(self, setpoints: Setpoints) -> None:
        self.sent.append(setpoints)

    def connect(self) -> None:
        self.connected = True


def stream(t0: float, n: int, offset: float) -> Setpoints:
    t = t0 + DT * np.arange(n)
    p = np.stack([t + offset, np.zeros(n), np.ones(n)], axis=1)[:, None, :]
    v = np.stack([np.ones(n), np.zeros(n), np.zeros(n)], axis=1)[:, None, :]
    return Setpoints(t, p, v)


def test_each_setpoint_is_executed_its_latency_later() -> None:
    inner = Recorder()
    robot = DelayedRobot(inner, 0.03)  # type: ignore[arg-type]
    robot.connect()
    assert inner.connected  # everything but send goes to the wrapped robot
    first, second = stream(0.0, 20, 0.0), stream(0.04, 20, 10.0)  # the second plan jumps by 10 m
    robot.send(first)
    robot.send(second)
    done = inner.sent
    assert [np.array_equal(d.t, s.t) for d, s in zip(done, (first, second), strict=True)] == [True, True]
    # Before the first setpoint is due (t < 0.03 s) the first position is held at rest.
    early = first.t < 0.03 - 1e-9
    assert np.all(done[0].position[early] == first.position[0]) and np.all(done[0].velocity[early] == 0.0)
    # After: what was commanded 30 ms before, from the first plan until the second one's times come due.
    late = ~early
    np.testing.assert_allclose(done[0].position[late, 0, 0], first.t[late] - 0.03)
    due = second.t - 0.03
    from_first = due < 0.04 - 1e-9
    np.testing.assert_allclose(done[1].position[from_first, 0, 0], due[from_first])
    np.testing.assert_allclose(done[1].position[~from_first, 0, 0], due[~from_first] + 10.0)
    assert np.all(done[1].velocity[:, 0, 0] == 1.0)


def test_no_latency_is_the_robot_itself_and_bad_latency_is_refused() -> None:
    inner = Recorder()
    s = stream(0.0, 5, 0.0)
    DelayedRobot(inner, 0.0).send(s)  # type: ignore[arg-type]
    assert inner.sent == [s]
    for bad in (-0.01, 1.5, float("nan")):
        with pytest.raises(ValueError, match="actuation latency"):
            DelayedRobot(inner, bad)  # type: ignore[arg-type]


@pytest.mark.slow
def test_demo_with_actuation_latency_records_it_and_changes_the_motion(tmp_path, capsys) -> None:
    """Seed 100000 through the loop: 40 ms of actuation latency changes the tip's path, and is recorded."""
    ends = {}
    for latency in ("0", "40"):
        out = tmp_path / latency
        argv = ["demo", "--observation", "true", "--seed", "100000", "--quiet", "--out", str(out),
                "--actuation-latency-ms", latency]
        assert main(argv) == 0
        metrics = json.loads((out / "metrics.json").read_text())
        assert metrics["actuation_latency_ms"] == float(latency)
        ends[latency] = metrics["episodes"][0]["min_distance_m"]
    assert ends["0"] != ends["40"]
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--out", str(tmp_path / "bad"), "--actuation-latency-ms", "-5"])
    assert exc.value.code == 2 and "--actuation-latency-ms" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
