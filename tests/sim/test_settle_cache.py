"""Settled initial states are reused within a process: only for exactly the same scene configuration."""

from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np

from dyndlo_vision.sim import scene as scene_module
from dyndlo_vision.sim.cable import CableParams
from dyndlo_vision.sim.scene import Scene, SceneConfig


def _config(**cable: float) -> SceneConfig:
    return SceneConfig(cable=CableParams(model="chain", **cable), settle_s=0.2,  # type: ignore[arg-type]
                       grippers_m=((0.5, 0.0, 0.6),), initial_path_m=((0.5, 0.0, 0.6), (0.9, 0.0, 0.1)))


def _roll(scene: Scene, steps: int = 300) -> np.ndarray:
    scene.reset()
    scene.set_tcp_reference(scene.gripper_home + [[0.05, 0.0, 0.02]], np.zeros((1, 3)))
    for _ in range(steps):
        mujoco.mj_step(scene.model, scene.data)
    return scene.data.qpos.copy()


def test_a_scene_built_again_starts_and_moves_exactly_as_one_settled_afresh(monkeypatch) -> None:
    config = _config()
    monkeypatch.setattr(scene_module, "_SETTLED", type(scene_module._SETTLED)())
    settled = Scene(config)
    cached = Scene(config)  # from the cache
    monkeypatch.setattr(scene_module, "_SETTLED", type(scene_module._SETTLED)())
    again = Scene(config)  # settled afresh
    np.testing.assert_array_equal(cached._initial_state, settled._initial_state)
    np.testing.assert_array_equal(again._initial_state, settled._initial_state)
    np.testing.assert_array_equal(cached.data.qpos, again.data.qpos)  # built settled, before any reset
    assert np.array_equal(_roll(cached), _roll(again))


def test_a_different_cable_is_settled_for_itself(monkeypatch) -> None:
    monkeypatch.setattr(scene_module, "_SETTLED", type(scene_module._SETTLED)())
    soft = Scene(_config())
    stiff = Scene(_config(young_pa=8e6))
    alone = Scene(replace(_config(young_pa=8e6)))
    assert not np.array_equal(stiff._initial_state, soft._initial_state)
    np.testing.assert_array_equal(stiff._initial_state, alone._initial_state)
    assert len(scene_module._SETTLED) == 2


def test_the_cache_keeps_only_the_newest_configurations(monkeypatch) -> None:
    monkeypatch.setattr(scene_module, "_SETTLED", type(scene_module._SETTLED)())
    monkeypatch.setattr(scene_module, "SETTLED_CACHE_SIZE", 2)
    for length in (0.48, 0.5, 0.52):
        Scene(_config(length_m=length))
    assert len(scene_module._SETTLED) == 2 and all("0.48" not in key for key in scene_module._SETTLED)
