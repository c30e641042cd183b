"""The push disturbance (issue 16): an impulse on one cable node, once per episode, in env and demo alike."""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest

import dyndlo_vision  # noqa: F401
from dyndlo_vision.cli import main
from dyndlo_vision.tasks.base import CablePush
from dyndlo_vision.tasks.registry import make_env


def _momentum(scene) -> np.ndarray:
    m, d = scene.model, scene.data
    mujoco.mj_forward(m, d)
    mujoco.mj_subtreeVel(m, d)
    return d.subtree_linvel[0] * m.body_subtreemass[0]


def test_an_impulse_changes_the_momentum_by_itself_and_moves_the_node_its_way() -> None:
    """Closed form: an impulse J changes the system's linear momentum by exactly J, and the pushed node's
    velocity by J over a positive effective mass (along J)."""
    env = make_env("tip-control", cable="chain")
    env.reset(seed=1)
    scene = env.unwrapped.scene
    n = scene.cable_nodes().shape[0]
    for node, impulse in ((n - 1, [0.01, 0.0, 0.0]), (n // 2, [0.0, 0.0, -0.004])):
        before = _momentum(scene)
        jac = np.zeros((3, scene.model.nv))
        mujoco.mj_jac(scene.model, scene.data, jac, None, scene.cable_nodes()[node],
                      int(scene._chain.bodies[min(node, n - 2)]))
        v_before = jac @ scene.data.qvel
        scene.push_cable(node, impulse)
        np.testing.assert_allclose(_momentum(scene) - before, impulse, atol=1e-12)
        dv = jac @ scene.data.qvel - v_before
        assert float(dv @ np.asarray(impulse)) > 0.0
        assert np.linalg.norm(np.cross(dv, impulse)) < 0.2 * np.linalg.norm(dv) * np.linalg.norm(impulse)
    for bad, message in ((0, "0 is held"), (n, "1.."), (True, "1..")):
        with pytest.raises(ValueError, match=message):
            scene.push_cable(bad, [0.0, 0.0, 0.01])
    with pytest.raises(ValueError, match="3 finite numbers"):
        scene.push_cable(1, [0.0, np.nan, 0.0])
    rod = make_env("tip-control", cable="rod")
    rod.reset(seed=1)
    with pytest.raises(ValueError, match="chain"):
        rod.unwrapped.scene.push_cable(1, [0.0, 0.0, 0.01])


def test_push_values_are_checked() -> None:
    with pytest.raises(ValueError, match="time"):
        CablePush(-0.1, (0.0, 0.0, 0.01))
    with pytest.raises(ValueError, match="impulse"):
        CablePush(0.1, (0.0, 0.01))  # type: ignore[arg-type]
    assert CablePush(0.1, [0, 0, 1]).impulse_n_s == (0.0, 0.0, 1.0)  # type: ignore[arg-type]


def _tip_track(env, action, push: CablePush | None) -> tuple[np.ndarray, dict]:
    env.unwrapped.cable_push = push
    env.reset(seed=3)
    tips = []
    env.unwrapped.frame_hook = lambda e: tips.append(e.p_dlo())
    info = env.step(action)[4]
    env.unwrapped.frame_hook = None
    return np.array(tips), info


def test_the_push_comes_once_per_episode_at_its_time() -> None:
    """The same single-step plan with and without a push: identical until the push time, different after;
    and a second episode is pushed again, exactly as the first."""
    env = make_env("tip-control", cable="chain")
    action = np.zeros(env.action_space.shape, np.float32)
    plain, _ = _tip_track(env, action, None)
    push = CablePush(0.2, (0.01, 0.0, 0.0))  # across the hanging cable (along it, the chain would not give)
    pushed, _ = _tip_track(env, action, push)
    again, _ = _tip_track(env, action, push)
    t = 0.04 * (np.arange(len(plain)) + 1)  # the frame hook runs every 40 ms of simulated time
    assert len(plain) == len(pushed) == len(again)
    before, after = t <= 0.2 + 1e-9, t > 0.2 + 1e-9
    np.testing.assert_array_equal(pushed[before], plain[before])
    assert np.abs(pushed[after] - plain[after]).max() > 0.01
    np.testing.assert_array_equal(again, pushed)


def test_demo_push_is_recorded_and_bad_values_are_refused(tmp_path: Path, capsys) -> None:
    out = tmp_path / "demo"
    argv = ["demo", "--observation", "true", "--seed", "100000", "--quiet", "--out", str(out)]
    assert main([*argv, "--push", "0.2,0,0,0.002"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["push"] == {"time_s": 0.2, "impulse_n_s": [0.0, 0.0, 0.002], "node": "middle"}
    for bad in ("0.2,0,0", "a,b,c,d", "-1,0,0,0.01"):
        with pytest.raises(SystemExit) as exc:
            main([*argv[:-1], str(tmp_path / "bad"), "--push", bad])
        assert exc.value.code == 2
        assert "push" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
