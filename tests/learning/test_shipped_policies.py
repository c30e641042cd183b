"""The policies shipped in the package load by name, match their metadata and still hit the target."""

from __future__ import annotations

import gymnasium as gym
import pytest

import dyndlo_vision  # noqa: F401
from dyndlo_vision import policies
from dyndlo_vision.learning.config import env_id


def test_both_tip_control_modes_are_shipped() -> None:
    assert {"tip-control-single-step", "tip-control-multi-step"} <= set(policies.available())
    for name in policies.available():
        meta = policies.metadata(name)
        assert meta["algo"] in ("ppo", "sac")
        if meta["task"] != "tip-control":
            continue
        assert meta["multi_step"] == name.endswith("multi-step")
        evaluation = meta["evaluation"]
        assert evaluation["episodes"] == 100 and evaluation["success_rate"] >= 0.9
        lo, hi = evaluation["success_ci95"]
        assert lo <= evaluation["success_rate"] <= hi


@pytest.mark.slow
@pytest.mark.parametrize("name", ["tip-control-single-step", "tip-control-multi-step"])
def test_shipped_policy_hits_unseen_targets(name: str) -> None:
    """Seeds 100000-100019 of the evaluation set (never trained on): 19/20 single-step, 20/20 multi-step."""
    meta = policies.metadata(name)
    env = gym.make(env_id(meta["task"]), multi_step=meta["multi_step"])
    model = policies.load(name, env=env)
    hits = 0
    for seed in range(100_000, 100_020):
        obs, _ = env.reset(seed=seed)
        done = False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, done, _, info = env.step(action)
        hits += bool(info["is_success"])
    assert hits >= 18, f"{name}: {hits}/20"


@pytest.mark.parametrize("name", [n for n in policies.available() if n.startswith("time-oscillation")])
def test_shipped_task_iv_policy_beats_the_geometric_lift_at_equal_time(name: str) -> None:
    """Task IV is deterministic: one episode is the policy. The geometric lift gets the same planned time."""
    import numpy as np

    from dyndlo_vision.tasks.baselines import GeometricLift

    meta = policies.metadata(name)
    env = gym.make(env_id(meta["task"]), **meta["env_options"])
    model = policies.load(name, env=env)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    base = env.unwrapped
    _, times = base.spec_actions.decode(
        action.astype(float), base.scene.gripper_home[0], 0.0, base.task.final_point(base.goal)
    )
    _, _, _, _, learned = env.step(action)
    obs, _ = env.reset(seed=0)
    _, _, _, _, geometric = env.step(GeometricLift(env, float(times[-1]))(obs))
    assert learned["is_success"] and not any(learned["avoid"].values())
    assert learned["residual_oscillation_m"] < geometric["residual_oscillation_m"]
    assert learned["residual_oscillation_m"] == pytest.approx(
        meta["evaluation"]["residual_oscillation_m"], abs=1e-3
    )
    assert np.isclose(times[-1], meta["evaluation"]["planned_time_s"], atol=1e-3)


@pytest.mark.slow
def test_shipped_hooking_policy_hooks_on_the_nominal_cable_and_on_cables_it_never_saw() -> None:
    """Hooking starts from one fixed state; cable variation is what tells (100/100 in its metadata)."""
    from dyndlo_vision.tasks.wrappers import CableRandomization

    meta = policies.metadata("hooking")
    assert meta["evaluation"]["success_rate"] >= 0.9
    env = gym.make(env_id("hooking"))
    model = policies.load("hooking", env=env)
    for episode_env in (env, CableRandomization(gym.make(env_id("hooking")), every_episodes=1)):
        for seed in range(100_000, 100_003):
            obs, start = episode_env.reset(seed=seed)
            action, _ = model.predict(obs, deterministic=True)
            _, _, _, _, info = episode_env.step(action)
            assert info["is_success"] and not any(info["avoid"].values()), (seed, start.get("cable"))


@pytest.mark.slow
def test_shipped_vaulting_policy_vaults_and_replays_its_recorded_cables() -> None:
    """Vaulting starts from one fixed state: the nominal cable is one episode. On random cables the policy
    succeeds only on some (stiff cables need another throw); the first recorded episodes must replay."""
    from dyndlo_vision.tasks.wrappers import CableRandomization

    meta = policies.metadata("vaulting")
    env = gym.make(env_id("vaulting"))
    model = policies.load("vaulting", env=env)
    obs, _ = env.reset(seed=0)
    _, reward, _, _, info = env.step(model.predict(obs, deterministic=True)[0])
    assert info["is_success"] and not any(info["avoid"].values())
    assert reward == pytest.approx(meta["evaluation"]["nominal_cable"]["reward"])
    random_cables = CableRandomization(gym.make(env_id("vaulting")), every_episodes=1)
    recorded = meta["evaluation"]["first_episodes"]
    successes = [seed for seed, ok in recorded.items() if ok][:2]
    failures = [seed for seed, ok in recorded.items() if not ok][:1]
    assert successes and failures  # the replay must be able to tell one from the other
    for seed in successes + failures:
        success = recorded[seed]
        obs, _ = random_cables.reset(seed=int(seed))
        _, _, _, _, info = random_cables.step(model.predict(obs, deterministic=True)[0])
        assert info["is_success"] == success, seed
