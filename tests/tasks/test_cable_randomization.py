"""Cable randomisation: a pure draw, handed to the environment's reset, which swaps the model, keeps hooks."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import dyndlo_vision  # noqa: F401  (registers the environment ids)
from dyndlo_vision.sim.cable import CableParams
from dyndlo_vision.tasks.wrappers import DEFAULT_CABLE_RANGES, draw_cable


def test_cable_randomization_draws_new_cables_deterministically() -> None:
    import gymnasium as gym

    from dyndlo_vision.tasks.wrappers import CableRandomization

    def lengths(seed: int) -> list[float]:
        env = CableRandomization(gym.make("DynDLO/TipControl-v0"), every_episodes=2)
        out = []
        for k in range(4):
            obs, info = env.reset(seed=seed if k == 0 else None)
            out.append(info["cable"].length_m)
            hanging = env.unwrapped.cable_nodes()
            # The rebuilt scene really has the drawn cable: the hanging tip is one cable length below the TCP.
            assert np.linalg.norm(hanging[-1] - hanging[0]) == pytest.approx(info["cable"].length_m, rel=0.03)
            env.step(np.zeros(env.action_space.shape, np.float32))
        return out

    first = lengths(3)
    assert first[0] == first[1] and first[2] == first[3] and first[0] != first[2]
    assert all(0.45 <= x <= 0.55 for x in first)
    assert lengths(3) == first
    with pytest.raises(ValueError, match="cannot randomise"):
        CableRandomization(gym.make("DynDLO/TipControl-v0"), ranges={"num_segments": (1, 2)})


def test_draw_cable_is_a_pure_function_of_its_generator_and_stays_in_range() -> None:
    nominal = CableParams()
    a = draw_cable(nominal, DEFAULT_CABLE_RANGES, np.random.default_rng(7))
    b = draw_cable(nominal, DEFAULT_CABLE_RANGES, np.random.default_rng(7))
    assert a == b and a != nominal
    assert nominal == CableParams()  # the nominal cable is not touched
    for _ in range(200):
        cable = draw_cable(nominal, DEFAULT_CABLE_RANGES, np.random.default_rng(_))
        for name, (lo, hi) in DEFAULT_CABLE_RANGES.items():
            assert lo * getattr(nominal, name) <= getattr(cable, name) <= hi * getattr(nominal, name)
        assert cable.num_segments == nominal.num_segments and cable.model == nominal.model


def test_draw_cable_spreads_stiffness_log_uniformly() -> None:
    rng = np.random.default_rng(0)
    nominal = CableParams()
    factors = np.array([draw_cable(nominal, {"young_pa": (0.5, 2.0)}, rng).young_pa for _ in range(4000)])
    factors /= nominal.young_pa
    # Log-uniform on [0.5, 2]: half the draws below 1 (uniform would put a third there).
    assert np.mean(factors < 1.0) == pytest.approx(0.5, abs=0.03)


def test_reset_with_a_cable_swaps_the_model_and_keeps_the_frame_hook() -> None:
    env = gym.make("DynDLO/TipControl-v0", multi_step=True)
    base = env.unwrapped
    calls: list[float] = []
    base.frame_hook = lambda e: calls.append(e.scene.time)
    base.batch_monitor = False
    env.reset(seed=0)
    scene = base.scene
    env.reset(seed=0, options={"cable": base.task.cable})  # the same cable: no recompilation
    assert base.scene is scene
    longer = CableParams(length_m=0.6)
    env.reset(seed=0, options={"cable": longer})
    assert base.scene is not scene and base.task.cable == longer
    nodes = base.cable_nodes()
    assert np.linalg.norm(nodes[-1] - nodes[0]) == pytest.approx(0.6, rel=0.03)
    assert base.frame_hook is not None and base.batch_monitor is False  # settings survive the swap
    env.step(np.zeros(env.action_space.shape, np.float32))
    assert calls  # the hook still fires on the new model


def test_reset_refuses_a_cable_that_is_not_cable_parameters() -> None:
    env = gym.make("DynDLO/TipControl-v0")
    with pytest.raises(ValueError, match="options\\['cable'\\] must be a CableParams, got dict"):
        env.reset(seed=0, options={"cable": {"length_m": 0.6}})


def test_cable_for_seed_is_the_cable_a_seeded_reset_draws() -> None:
    """What benchmarks and diagnostics use to know an episode's cable without resetting an environment."""
    from dyndlo_vision.tasks.wrappers import CableRandomization, cable_for_seed, cable_ranges_for

    ranges = cable_ranges_for("tip-control", "beyond")
    env = CableRandomization(gym.make("DynDLO/TipControl-v0"), ranges=ranges, every_episodes=1)
    nominal = env.unwrapped.task.cable
    for seed in (100000, 100001):
        _, info = env.reset(seed=seed)
        assert info["cable"] == cable_for_seed(nominal, ranges, seed)
    assert cable_for_seed(nominal, ranges, 100000) != cable_for_seed(nominal, ranges, 100001)
    env.close()


def test_random_cables_are_checked_when_made_and_draw_the_tasks_ranges() -> None:
    """:class:`RandomCables`, the one setting behind every command's --randomize-cable and --cable-ranges."""
    from dyndlo_vision.tasks.wrappers import BEYOND_TRAINING_CABLE_RANGES, RandomCables

    assert RandomCables().env_options("tip-control") == {"randomize_cable_every": 1,
                                                         "cable_ranges": DEFAULT_CABLE_RANGES}
    beyond = RandomCables("beyond", every_episodes=10).env_options("vaulting")
    assert beyond["randomize_cable_every"] == 10
    assert beyond["cable_ranges"] == {**BEYOND_TRAINING_CABLE_RANGES, "length_m": (0.9, 1.2)}  # they fit
    with pytest.raises(ValueError, match="cable ranges 'wide'; expected one of \\['beyond', 'training'\\]"):
        RandomCables("wide")
    with pytest.raises(ValueError, match="a new cable every 0 episodes; expected an integer >= 1"):
        RandomCables(every_episodes=0)
