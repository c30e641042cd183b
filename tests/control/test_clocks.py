"""ClockSync: a live camera's monotonic time stamps put on the robot's clock."""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision.cameras.devices import OpenCVDeviceCamera
from dyndlo_vision.cameras.files import VideoFileCamera
from dyndlo_vision.cameras.protocol import CAMERA_CLOCKS
from dyndlo_vision.cameras.simulated import DelayedCamera, MujocoCamera
from dyndlo_vision.control.clocks import ClockSync


def test_offset_is_the_freshest_pair_and_never_ahead_of_the_truth() -> None:
    """States read at a random age (up to one 4 ms EGM cycle plus transport): the estimate is the pair
    with the smallest age, so it falls short of the true offset by at most that age, never beyond it."""
    rng = np.random.default_rng(0)
    true_offset = -51_234.567  # robot clock: seconds since the controller started; local: monotonic
    sync = ClockSync(window=250)
    ages = rng.uniform(0.0005, 0.006, size=250)
    for k, age in enumerate(ages):
        local = 60_000.0 + 0.04 * k
        sync.observe(local + true_offset - age, local)
    assert true_offset - ages.min() == pytest.approx(sync.offset_s, abs=1e-9)
    assert sync.offset_s <= true_offset
    assert sync.to_robot(60_001.0) == pytest.approx(60_001.0 + true_offset, abs=0.001)


def test_window_follows_a_drifting_clock() -> None:
    sync = ClockSync(window=10)
    for k in range(100):
        local = 0.04 * k
        sync.observe(local * (1 + 1e-3) + 5.0, local)  # the robot's clock runs 1000 ppm fast
    assert sync.offset_s == pytest.approx(5.0 + 1e-3 * 0.04 * 99, abs=1e-12)  # the latest, not the first


def test_a_restarted_robot_clock_drops_the_old_pairs() -> None:
    sync = ClockSync()
    sync.observe(100.0, 10.0)
    sync.observe(100.04, 10.04)
    sync.observe(0.5, 10.08)  # the controller restarted: its clock began again
    assert sync.offset_s == pytest.approx(0.5 - 10.08)


def test_default_local_clock_is_used_when_no_local_time_is_given() -> None:
    ticks = iter([7.0, 8.0])
    sync = ClockSync(clock=lambda: next(ticks))
    sync.observe(2.0)
    assert sync.offset_s == pytest.approx(-5.0)


def test_bad_input_is_named() -> None:
    with pytest.raises(ValueError, match="window"):
        ClockSync(window=0)
    with pytest.raises(ValueError, match="window"):
        ClockSync(window=2.5)  # type: ignore[arg-type]
    sync = ClockSync()
    assert not sync.ready
    with pytest.raises(RuntimeError, match="observe"):
        sync.to_robot(1.0)
    for bad in (float("nan"), float("inf"), "1.0", None):
        with pytest.raises(ValueError, match="robot_t"):
            sync.observe(bad, 0.0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="local_t"):
        sync.observe(1.0, float("nan"))
    assert not sync.ready


def test_cameras_name_their_clock() -> None:
    assert MujocoCamera.clock == "simulation"
    assert VideoFileCamera.clock == "video"
    assert OpenCVDeviceCamera.clock == "monotonic"
    assert {MujocoCamera.clock, VideoFileCamera.clock, OpenCVDeviceCamera.clock} == set(CAMERA_CLOCKS)

    class Live:
        clock = "monotonic"

    assert DelayedCamera(Live(), 0.04).clock == "monotonic"
    assert DelayedCamera(object(), 0.04).clock is None
