"""`dyndlo-vision run CONFIG.yaml --dry-run`: the shipped examples end to end against the fake controllers,
and every way a run must refuse to start (exit status 2, the reason named, no output folder)."""

from __future__ import annotations

import json
import socket
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from dyndlo_vision import policies
from dyndlo_vision.cli import main
from dyndlo_vision.control import dry_run
from dyndlo_vision.robots.feasibility import ROBOT_ARMS
from dyndlo_vision.robots.kinematics import check_joint_limits

pytest.importorskip("abb_robot_client")

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


#: A target the scripted slow reach gets the tip to (it carries the hanging cable; the examples' target, the
#: centre of the policy's training targets, is beyond it).
SLOW_REACH_TARGET = [0.62, 0.0, 0.2]


def config(tmp_path: Path, example: str = "run-gofa-dry.yaml", name: str = "cfg.yaml",
           **changes: Any) -> Path:
    """An example's config with ``changes`` (dotted keys; None deletes), written into tmp_path."""
    data = yaml.safe_load((EXAMPLES / example).read_text())
    data["camera"]["calibration"] = str(EXAMPLES / data["camera"]["calibration"])
    for key, value in changes.items():
        *parents, last = key.split(".")
        node = data
        for p in parents:
            node = node[p]
        if value is None:
            node.pop(last, None)
        else:
            node[last] = value
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def refused(capsys: pytest.CaptureFixture[str], out: Path, *argv: str) -> str:
    """Run, expect exit status 2 and no output folder; return the error line."""
    with pytest.raises(SystemExit) as exc:
        main(["run", *argv, "--out", str(out)])
    assert exc.value.code == 2
    assert not out.exists(), "a refused run left an output folder"
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("dyndlo-vision run: error: ")
    return err


def spy_fake(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """Keep the fake controllers the runs start."""
    fakes: list[Any] = []
    start = dry_run.start_fake_controller

    def spy(*args: Any, **kwargs: Any) -> Any:
        fakes.append(start(*args, **kwargs))
        return fakes[-1]

    monkeypatch.setattr(dry_run, "start_fake_controller", spy)
    return fakes


@pytest.mark.slow
@pytest.mark.parametrize("example", ["run-gofa-dry.yaml", "run-ur5e-dry.yaml"])
def test_example_runs_dry(example: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                          capsys: pytest.CaptureFixture[str]) -> None:
    fakes = spy_fake(monkeypatch)
    out = tmp_path / "out"
    assert main(["run", str(EXAMPLES / example), "--dry-run", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json", "p_dlo.png", "robot.png", "run.mp4"]
    m = json.loads((out / "metrics.json").read_text())
    assert m["exit_status"] == 0 and m["stop_reason"] == "plan finished" and m["driver_fault"] is None
    # The example's policy is shipped: it runs, not the fallback.
    assert m["policy"] == yaml.safe_load((EXAMPLES / example).read_text())["policy"]
    assert m["policy"] in policies.available() and m["policy_note"] is None
    # The simulation's truth decides the outcome.
    assert m["success"] is True and m["min_distance_m"] < 0.035
    # The robot received every joint target sent while it moved (and, for EGM, every answer).
    sp = m["setpoints"]
    assert sp["joint_targets_sent_moving"] > 200
    assert sp["moving_targets_lost"] == 0
    # At most the last (a repeat of the rest position) overwritten by the halt command on close (RTDE).
    assert 0 <= sp["joint_targets_lost"] <= (1 if "ur5e" in example else 0)
    assert sp["plans_sent"] == 1 and sp["cycles_without_new_plan"] == m["cycles"] - 1  # single-step
    assert sp["plan_max_late_s"] < 0.0, "a plan was accepted after its start"
    # No joint limit broken: over what the driver streamed (metrics) and over what the fake robot received.
    for limits in ("arm_limits", "margin_limits"):
        usage = m["joint_limits"][limits]
        assert usage["velocity_fraction"] < 1.0 and usage["acceleration_fraction"] < 1.0
        assert usage["position_margin_deg"] > 0.0
    (fake,) = fakes
    received = fake.received
    t = np.array([r.t for r in received])
    q = np.array([r.q for r in received])
    moving = np.flatnonzero(np.any(np.abs(np.diff(q, axis=0)) > 0, axis=1))
    assert moving.size > 100
    arm = ROBOT_ARMS["gofa" if "gofa" in example else "ur5e"].model()
    assert check_joint_limits(arm, t, q).ok
    # The fake robot ended at rest where the plan ended.
    assert np.allclose(fake.q, q[-1], atol=1e-4)
    assert m["video"]["frames"] == m["cycles"] + 1
    assert "plan finished" in capsys.readouterr().out


def test_missing_config_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    err = refused(capsys, tmp_path / "out", str(tmp_path / "nope.yaml"), "--dry-run")
    assert "config file not found" in err and "nope.yaml" in err


def test_unknown_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = config(tmp_path, **{"safety.max_speed": 1.0})
    err = refused(capsys, tmp_path / "out", str(cfg), "--dry-run")
    assert "unknown key(s) ['safety.max_speed']" in err and "max_tcp_speed" in err


@pytest.mark.parametrize(
    ("key", "value", "expected"),
    [
        ("robot.arm", "kuka", "robot.arm: got 'kuka'; expected one of ['gofa', 'ur5e']"),
        ("robot.arm", "ur5e", "robot.arm: got 'ur5e'; expected 'gofa': the egm driver streams to the gofa"),
        ("safety.joint_margin", 1.5, "safety.joint_margin: got 1.5; expected a number in (0, 1]"),
        ("target", [0.8, 0.0], "target: got [0.8, 0.0]; expected a list of 3 finite numbers"),
        ("camera.source", "webcam", "camera.source: got 'webcam'; expected one of"),
        ("robot.host", "10.0.0.2", "robot.host: got '10.0.0.2'; expected no host for egm"),
        ("safety.workspace.max", [0.1, 0.3, 1.0],
         "safety.workspace.max: got [0.1, 0.3, 1.0]; expected above"),
    ],
)
def test_bad_value(key: str, value: Any, expected: str, tmp_path: Path,
                   capsys: pytest.CaptureFixture[str]) -> None:
    cfg = config(tmp_path, **{key: value})
    assert expected in refused(capsys, tmp_path / "out", str(cfg), "--dry-run")


def test_missing_calibration(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = config(tmp_path, **{"camera.calibration": "no-such-camera.json"})
    err = refused(capsys, tmp_path / "out", str(cfg), "--dry-run")
    assert "camera.calibration: file not found" in err and "no-such-camera.json" in err


def test_unknown_policy(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = config(tmp_path, policy="tip-control-no-such-policy", fallback_policy=None)
    err = refused(capsys, tmp_path / "out", str(cfg), "--dry-run")
    assert "policy" in err and "tip-control-no-such-policy" in err and "neither a file nor a shipped" in err
    cfg = config(tmp_path, name="cfg2.yaml", policy="scripted:fast-whip")
    err = refused(capsys, tmp_path / "out", str(cfg), "--dry-run")
    assert "policy: got 'scripted:fast-whip'" in err and "scripted:slow-reach" in err


@pytest.mark.slow
@pytest.mark.parametrize("example", ["run-gofa-dry.yaml", "run-ur5e-dry.yaml"])
def test_first_plan_breaking_a_joint_limit_is_refused(example: str, tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """Today's shipped single-step policy whips faster than either arm's joints can accelerate."""
    fakes = spy_fake(monkeypatch)
    cfg = config(tmp_path, example, policy="tip-control-single-step", fallback_policy=None)
    err = refused(capsys, tmp_path / "out", str(cfg), "--dry-run")
    assert "first plan refused, nothing sent: joint" in err
    assert "acceleration" in err and "breaks the limit" in err and "rad/s^2" in err
    joint = "axis_2" if "gofa" in example else "elbow"
    assert f"joint {joint} acceleration" in err
    # Nothing moved: the fake robot never received a moving target.
    (fake,) = fakes
    q = np.array([r.q for r in fake.received])
    assert q.size == 0 or np.all(np.abs(q - q[0]) < 1e-12)


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_unreachable_egm_robot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = config(tmp_path, **{"robot.port": _free_port(socket.SOCK_DGRAM), "robot.connect_timeout_s": 0.5})
    err = refused(capsys, tmp_path / "out", str(cfg))
    assert "robot unreachable: an ABB controller sending EGM to UDP port" in err
    assert "no state from the robot within 0.5 s" in err


def test_unreachable_rtde_robot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    port = _free_port(socket.SOCK_STREAM)
    cfg = config(tmp_path, "run-ur5e-dry.yaml", **{"robot.host": "127.0.0.1", "robot.port": port,
                                                    "robot.connect_timeout_s": 0.5})
    err = refused(capsys, tmp_path / "out", str(cfg))
    assert f"robot unreachable: the UR controller at 127.0.0.1:{port} (RTDE)" in err


@pytest.mark.slow
def test_silent_robot_brakes_and_reports(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """The controller stops answering mid-plan: the driver faults, the run stops with the reason."""
    fakes = spy_fake(monkeypatch)
    timers: list[threading.Timer] = []
    start = dry_run.start_fake_controller  # the spy

    def hang_later(*args: Any, **kwargs: Any) -> Any:
        fake = start(*args, **kwargs)
        timers.append(threading.Timer(1.2, fake.hang))
        timers[-1].start()
        return fake

    monkeypatch.setattr(dry_run, "start_fake_controller", hang_later)
    out = tmp_path / "out"
    assert main(["run", str(EXAMPLES / "run-gofa-dry.yaml"), "--dry-run", "--out", str(out)]) == 1
    m = json.loads((out / "metrics.json").read_text())
    assert m["stop_reason"].startswith("robot fault: watchdog: the robot stopped answering")
    assert m["exit_status"] == 1 and m["cycles"] > 0
    assert "stopped early: robot fault" in capsys.readouterr().err
    assert len(fakes) == 1


@pytest.mark.slow
def test_ctrl_c_brakes_and_reports(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    fakes = spy_fake(monkeypatch)
    read = dry_run.FollowingCamera.read
    calls = {"n": 0}

    def interrupted(self: Any) -> Any:
        # Pressed once the arm is moving (mid-plan), whenever that is: a frame count is not, on a loaded
        # machine (the 25th frame came after the plan's end, the 6th before the arm moved).
        calls["n"] += 1
        if fakes and not calls.get("pressed"):
            q = np.array([r.q for r in list(fakes[0].received)])
            if len(q) > 1 and np.max(np.abs(q - q[0])) > 0.01:  # rad
                calls["pressed"] = 1
                raise KeyboardInterrupt
        return read(self)

    monkeypatch.setattr(dry_run.FollowingCamera, "read", interrupted)
    out = tmp_path / "out"
    assert main(["run", str(EXAMPLES / "run-ur5e-dry.yaml"), "--dry-run", "--out", str(out)]) == 130
    m = json.loads((out / "metrics.json").read_text())
    assert m["stop_reason"] == "interrupted (Ctrl-C)" and m["exit_status"] == 130
    assert "stopped early: interrupted (Ctrl-C)" in capsys.readouterr().err
    # Braked to rest within the limits: what the robot received is joint-feasible and ends still.
    (fake,) = fakes
    t = np.array([r.t for r in fake.received])
    q = np.array([r.q for r in fake.received])
    assert check_joint_limits(ROBOT_ARMS["ur5e"].model(), t, q).ok
    assert np.all(np.abs(q[-1] - q[-2]) / (t[-1] - t[-2]) < 0.02)  # rad/s: at rest
    assert np.max(np.abs(np.diff(q, axis=0)) / np.diff(t)[:, None]) > 0.1  # rad/s: it was moving, it braked


@pytest.mark.slow
def test_multi_step_replans_join_on_the_robot(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Re-planning every 40 ms on the UR5e: every plan accepted before it starts, none breaks a limit."""
    fakes = spy_fake(monkeypatch)
    # The configured lead (80 ms); on a loaded machine it adapts to the cycle latency.
    cfg = config(tmp_path, "run-ur5e-dry.yaml", policy="scripted:slow-reach-replan", fallback_policy=None,
                 target=SLOW_REACH_TARGET)
    out = tmp_path / "out"
    assert main(["run", str(cfg), "--dry-run", "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["multi_step"] is True and m["stop_reason"] in ("plan finished", "target hit")
    sp = m["setpoints"]
    # One plan per cycle over 1.6 s of re-planning (40 cycles unloaded; 10-18 with three busy processes beside
    # it), each sent or, predicted to arrive after its start, dropped: the lead adapts to the load, but on a
    # loaded machine the IK of each plan can outlast it (up to 14 of 18 dropped with three busy processes). A
    # send slower than predicted may still arrive a little late (17 ms in one CI run), joined within limits.
    assert sp["plans_sent"] + sp["plans_late"] == m["cycles"] >= 10 and sp["plans_sent"] >= 4
    assert sp["plan_lead_s"] <= sp["plan_lead_max_used_s"] <= 0.22
    assert sp["moving_targets_lost"] == 0 and sp["joint_targets_lost"] <= 1
    assert m["joint_limits"]["margin_limits"]["acceleration_fraction"] < 1.0
    (fake,) = fakes
    t = np.array([r.t for r in fake.received])
    q = np.array([r.q for r in fake.received])
    assert check_joint_limits(ROBOT_ARMS["ur5e"].model(), t, q).ok
    # Frames continue while the last plan runs out after the re-planning.
    assert m["video"]["frames"] > m["cycles"] + 5


@pytest.mark.slow
def test_video_camera_replayed_against_the_fake_robot(tmp_path: Path) -> None:
    """camera.source video: frames of the scene (a folder of PNGs) and its background, tracked as if live."""
    import cv2

    from dyndlo_vision.cameras.simulated import MujocoCamera
    from dyndlo_vision.control.sim_perception import render_without_cable
    from dyndlo_vision.tasks.registry import make_env

    env = make_env("tip-control")
    env.reset(seed=0, options={"goal": (0.62, 0.0, 0.2)})
    base = env.unwrapped
    frames = tmp_path / "frames"
    frames.mkdir()
    with MujocoCamera(base.model, base.data, "tracking") as cam:
        cv2.imwrite(str(tmp_path / "empty.png"), cv2.cvtColor(render_without_cable(cam), cv2.COLOR_RGB2BGR))
        image = cv2.cvtColor(cam.read().rgb, cv2.COLOR_RGB2BGR)
    for i in range(60):  # the cable hanging still
        cv2.imwrite(str(frames / f"f{i}.png"), image)
    cfg = config(tmp_path, camera={"source": "video", "path": str(frames), "fps": 25,
                                   "calibration": str(EXAMPLES / "tracking-camera.json"),
                                   "segmenter": "background", "background": str(tmp_path / "empty.png")})
    out = tmp_path / "out"
    assert main(["run", str(cfg), "--dry-run", "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["camera"] == "video" and m["stop_reason"] == "plan finished"
    assert m["success"] is None and "no simulation" in m["truth"]  # nothing says where the real tip went
    assert m["measured_cycles"] > 0
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json", "robot.png", "run.mp4"]


@pytest.mark.slow
def test_lost_estimate_brakes_and_reports(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """Re-planning (multi-step) on a camera that stops delivering: the estimate is lost, the arm brakes."""
    fakes = spy_fake(monkeypatch)
    read = dry_run.FollowingCamera.read
    calls = {"n": 0}

    def dies(self: Any) -> Any:
        calls["n"] += 1
        return read(self) if calls["n"] < 12 else None

    monkeypatch.setattr(dry_run.FollowingCamera, "read", dies)
    cfg = config(tmp_path, policy="scripted:slow-reach-replan", fallback_policy=None,
                 target=SLOW_REACH_TARGET)
    out = tmp_path / "out"
    assert main(["run", str(cfg), "--dry-run", "--out", str(out)]) == 1
    m = json.loads((out / "metrics.json").read_text())
    assert m["stop_reason"] == "P_DLO estimate lost (the camera lost the cable)"
    assert m["lost_cycles"] == 1 and 8 <= m["cycles"] <= 20  # frames stop after 11 cycles; coasting ends
    assert "stopped early: P_DLO estimate lost" in capsys.readouterr().err
    (fake,) = fakes
    t = np.array([r.t for r in fake.received])
    q = np.array([r.q for r in fake.received])
    assert check_joint_limits(ROBOT_ARMS["gofa"].model(), t, q).ok
    assert np.all(np.abs(q[-1] - q[-2]) / (t[-1] - t[-2]) < 0.02)  # braked to rest


@pytest.mark.slow
def test_fallback_policy_when_the_policy_is_not_installed(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    cfg = config(tmp_path, "run-ur5e-dry.yaml", policy="tip-control-single-step-kr6",
                 fallback_policy="scripted:slow-reach", target=SLOW_REACH_TARGET)
    out = tmp_path / "out"
    assert main(["run", str(cfg), "--dry-run", "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["policy"] == "scripted:slow-reach" and m["policy_requested"] == "tip-control-single-step-kr6"
    assert "'tip-control-single-step-kr6' is not installed" in m["policy_note"]
    assert m["success"] is True and m["setpoints"]["moving_targets_lost"] == 0
    assert "note: policy 'tip-control-single-step-kr6' is not installed" in capsys.readouterr().out
