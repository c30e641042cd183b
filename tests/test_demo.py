"""The main job, `dyndlo-vision demo`, end to end on its shipped defaults."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from dyndlo_vision.cli import main
from dyndlo_vision.commands import demo
from dyndlo_vision.learning.evaluate import wilson_interval


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


# ---------------------------------------------------------------- fast: the command around the episodes


def fake_record(seed: int, success: bool, cycle_ms: list[float]) -> dict[str, Any]:
    """What ``run_episode`` returns, made up: a hit ends 1 cm from the target, a miss 20 cm."""
    distance = 0.01 if success else 0.2
    goal = [0.8, 0.0, 0.4]
    tip = [0.8 + distance, 0.0, 0.4]
    return {
        "seed": seed, "success": success, "final_distance_m": distance, "min_distance_m": distance / 2,
        "estimate_rmse_m": 0.001 * (seed % 7),
        "cycle_ms_p50": float(np.percentile(cycle_ms, 50)),
        "cycle_ms_p95": float(np.percentile(cycle_ms, 95)),
        "stage_ms_p50": {}, "stage_ms_p95": {}, "deadline_misses": 1, "cycles": len(cycle_ms),
        "stop_reason": "done" if success else "duration", "avoid": {},
        "trace": {"t": [0.0, 0.04], "true": [tip, tip], "estimate": [tip, tip], "measured": [True, False],
                  "goal": goal},
        "_cycle_ms": cycle_ms, "_stage_ms": {"camera": cycle_ms},
    }


@pytest.fixture
def fake_episodes(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Replace the policy and the episodes by stand-ins (seeds ending in 1 miss); returns the seeds run."""
    from dyndlo_vision import policies

    seeds: list[int] = []

    def run_episode(env: Any, model: Any, seed: int, observation: str, camera_name: str,
                    video: list[np.ndarray] | None, **kwargs: Any) -> dict[str, Any]:
        seeds.append(seed)
        if video is not None:
            video.extend(np.full((48, 64, 3), 60 * k, dtype=np.uint8) for k in range(3))
        return fake_record(seed, seed % 10 != 1, [1.0, 2.0, 3.0])

    monkeypatch.setattr(policies, "load", lambda *args, **kwargs: object())
    monkeypatch.setattr(demo, "run_episode", run_episode)
    return seeds


def test_summarize_aggregates_all_episodes_instead_of_reporting_the_first() -> None:
    # Episode 0 misses, so its numbers differ from the run's.
    records = [fake_record(2, False, [10.0, 20.0]), fake_record(1, True, [1.0, 2.0, 3.0]),
               fake_record(3, True, [4.0])]
    metrics = demo.summarize(records)
    assert metrics["num_episodes"] == 3 and metrics["successes"] == 2
    assert metrics["success_rate"] == pytest.approx(2 / 3)
    assert metrics["success_ci95"] == list(wilson_interval(2, 3))
    assert metrics["final_distance_m_median"] == 0.01 and metrics["min_distance_m_median"] == 0.005
    assert metrics["estimate_rmse_m_median"] == np.median([r["estimate_rmse_m"] for r in records])
    # Percentiles over the six cycles pooled (3.5 ms), not episode 0's (15 ms) nor a median of medians (4 ms).
    assert metrics["cycle_ms_p50"] == 3.5
    assert metrics["cycle_ms_p95"] == pytest.approx(np.percentile([10, 20, 1, 2, 3, 4], 95))
    assert metrics["stage_ms_p50"] == {"camera": 3.5}
    assert metrics["cycles"] == 6 and metrics["deadline_misses"] == 3
    assert "success" not in metrics and "final_distance_m" not in metrics
    assert [r["seed"] for r in metrics["episodes"]] == [2, 1, 3]
    assert all("trace" not in r and "_cycle_ms" not in r for r in metrics["episodes"])
    one = demo.summarize(records[:1])
    assert one["success"] is False and one["final_distance_m"] == 0.2 and one["success_rate"] == 0.0


def test_demo_progress_bar_for_several_episodes_and_quiet_turns_it_off(
    tmp_path: Path, fake_episodes: list[int], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["demo", "--out", str(tmp_path / "a"), "--episodes", "3", "--seed", "100000"]) == 0
    captured = capsys.readouterr()
    assert "demo episodes" in captured.err and "3/3" in captured.err
    assert captured.out.count("episode ") >= 3 and "success rate 2/3" in captured.out
    assert main(["demo", "--out", str(tmp_path / "b"), "--episodes", "3", "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "demo episodes" not in captured.err and "3/3" not in captured.err
    assert "success rate 2/3" in captured.out
    assert main(["demo", "--out", str(tmp_path / "c")]) == 0  # one episode: no bar
    assert "demo episodes" not in capsys.readouterr().err
    metrics = json.loads((tmp_path / "a" / "metrics.json").read_text())
    assert metrics["success_rate"] == pytest.approx(2 / 3) and len(metrics["episodes"]) == 3


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
    assert list(tmp_path.iterdir()) == []


def test_demo_out_that_is_a_file_is_an_error_before_any_work(
    tmp_path: Path, fake_episodes: list[int], capsys: pytest.CaptureFixture[str]
) -> None:
    """It was a FileExistsError traceback (``mkdir``), after the policy had been loaded."""
    existing = tmp_path / "results.txt"
    existing.write_text("mine")
    for out, message in ((existing, "is an existing file; expected a folder"),
                         (existing / "demo", "results.txt is a file, so no folder can be created under it")):
        with pytest.raises(SystemExit) as exc:
            main(["demo", "--out", str(out)])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert message in err and str(existing) in err and "Traceback" not in err
    assert fake_episodes == []  # checked before any episode ran
    assert existing.read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["results.txt"]


def test_demo_unknown_camera_lists_the_cameras_and_leaves_no_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """It used to fail in the first episode, after the output folder had been made: an empty folder."""
    from dyndlo_vision import policies

    def no_load(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("the policy was loaded before the camera was checked")

    monkeypatch.setattr(policies, "load", no_load)
    out = tmp_path / "new" / "demo"
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--out", str(out), "--camera", "nosuchcam"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--camera 'nosuchcam' is not a camera of the scene; expected one of" in err
    assert "'tracking'" in err and "'front'" in err
    assert list(tmp_path.iterdir()) == []


def test_demo_that_fails_while_writing_leaves_no_new_folder_and_no_partial_outputs(
    tmp_path: Path, fake_episodes: list[int], monkeypatch: pytest.MonkeyPatch
) -> None:
    def broken_plot(path: Path, trace: dict[str, Any]) -> None:
        raise RuntimeError("plotting failed")

    monkeypatch.setattr(demo, "_write_plot", broken_plot)
    with pytest.raises(RuntimeError, match="plotting failed"):
        main(["demo", "--out", str(tmp_path / "new" / "demo")])
    assert list(tmp_path.iterdir()) == []  # the video was written already: into the staging folder, now gone
    old = tmp_path / "old"
    old.mkdir()
    (old / "metrics.json").write_text("previous run")
    with pytest.raises(RuntimeError, match="plotting failed"):
        main(["demo", "--out", str(old)])
    assert [p.name for p in old.iterdir()] == ["metrics.json"] and (old / "metrics.json").read_text() == (
        "previous run"
    )


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
