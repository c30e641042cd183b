"""The main job, `dyndlo-vision demo`, end to end on its shipped defaults."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest

from dyndlo_vision.cli import main


@pytest.mark.slow
def test_demo_writes_video_plot_and_metrics(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("success", "final_distance_m", "estimate_rmse_m", "cycle_ms_p50", "cycle_ms_p95"):
        assert key in metrics
    # The default is the shipped multi-step policy; on seed 100000 it hits after 16 cycles (0.64 s).
    assert metrics["observation"] == "tracked" and metrics["multi_step"] is True and metrics["cycles"] > 10
    assert 0.0 < metrics["estimate_rmse_m"] < 0.1  # measured 11 mm on this seed
    video = cv2.VideoCapture(str(out / "demo.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == metrics["cycles"]
    plot = cv2.imread(str(out / "p_dlo.png"))
    assert plot is not None and plot.shape[0] > 300


def test_demo_rejects_bad_input_and_writes_nothing(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    for argv in (
        ["--episodes", "0"],
        ["--policy", str(tmp_path / "missing.zip")],
        ["--latency-ms", "-5"],
        ["--latency-ms", "nan"],
        ["--latency-ms", "300"],
        ["--latency-ms", "40", "--observation", "true"],
    ):
        with pytest.raises(SystemExit) as exc:
            main(["demo", "--out", str(out), *argv])
        assert exc.value.code == 2
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.slow
@pytest.mark.parametrize("seed", [100000, 100056])
def test_demo_loop_on_true_state_is_the_environment_episode(seed: int) -> None:
    """The demo's loop on true state scores a multi-step episode exactly as ``env.step`` does.

    Seed 100056 misses and runs all 40 decisions: after the last re-plan the environment follows that plan for
    the settle time, and so must the loop (holding the TCP instead once changed the outcome of this seed).
    """
    import gymnasium as gym
    import numpy as np

    from dyndlo_vision import policies
    from dyndlo_vision.commands.demo import run_episode

    env = gym.make("DynDLO/TipControl-v0", multi_step=True)
    model = policies.load("tip-control-multi-step", env=env)
    obs, _ = env.reset(seed=seed)
    done, steps = False, 0
    while not done:
        action, _ = model.predict(obs, deterministic=True)
        obs, _, done, _, info = env.step(action)
        steps += 1
    end_time = env.unwrapped.scene.time
    record = run_episode(env, model, seed, "true", "tracking", None)
    assert record["cycles"] == steps
    assert record["success"] == info["is_success"] and record["avoid"] == info["avoid"]
    assert record["min_distance_m"] == pytest.approx(info["min_distance_m"], abs=1e-9)
    assert env.unwrapped.scene.time == pytest.approx(end_time)
    assert np.isfinite(record["final_distance_m"])
