"""The main job, `dyndlo-vision demo`, end to end on its shipped defaults, and its outputs' agreement."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from dyndlo_vision.cli import main
from dyndlo_vision.commands import demo
from dyndlo_vision.learning.evaluate import wilson_interval
from dyndlo_vision.tasks.tip_control import TipControl

PERIOD_S = 0.04


def read_video(path: Path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            return frames
        frames.append(frame)


def spy_outputs(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """Record the frames the demo encodes and the trace it plots (the real writers still run)."""
    seen: dict[str, Any] = {}
    write_video, write_plot = demo.write_video_atomic, demo._write_plot

    def video(path: Path, frames: list[np.ndarray], **kwargs: Any) -> str:
        seen["frames"] = list(frames)
        return write_video(path, frames, **kwargs)

    def plot(path: Path, trace: dict[str, Any], *args: Any) -> None:
        seen["trace"] = trace
        write_plot(path, trace, *args)

    monkeypatch.setattr(demo, "write_video_atomic", video)
    monkeypatch.setattr(demo, "_write_plot", plot)
    return seen


def true_tip_marker_px(frame_bgr: np.ndarray) -> np.ndarray:
    """Centre of the white ring marking the true P_DLO (pure white pixels, leaving out status and legend)."""
    h = frame_bgr.shape[0]
    rows, cols = np.nonzero(np.all(frame_bgr[45 : h - 30] == 255, axis=2))
    assert rows.size > 10, "no true P_DLO marker in the frame"
    return np.array([cols.mean(), rows.mean() + 45])


@pytest.mark.slow
def test_demo_hits_and_its_video_plot_and_metrics_agree(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The default episode hits, and the video and plot end where metrics.json measures the final distance.

    They used to stop at the start of the last control cycle, 40 ms (about 5 cm of whipped tip) before the
    state metrics.json scores: the last frame showed a miss beside a reported hit.
    """
    import gymnasium as gym

    from dyndlo_vision.cameras.simulated import MujocoCamera

    seen = spy_outputs(monkeypatch)
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    for key in ("success", "final_distance_m", "estimate_rmse_m", "cycle_ms_p50", "cycle_ms_p95"):
        assert key in metrics
    # The default is the shipped multi-step policy; on seed 100000 it hits in the 16th cycle (by 0.64 s).
    assert metrics["observation"] == "tracked" and metrics["multi_step"] is True and metrics["cycles"] > 10
    assert metrics["success"] is True and metrics["stop_reason"] == "done"
    assert metrics["final_distance_m"] < TipControl().success_radius_m  # measured 16 mm; radius 35 mm
    assert 0.0 < metrics["estimate_rmse_m"] < 0.1  # measured 11 mm on this seed
    (episode,) = metrics["episodes"]
    end_t = episode["end_time_s"]
    assert end_t == pytest.approx(PERIOD_S * metrics["cycles"])

    # The plot's truth ends at that instant, on the tip metrics.json measured.
    trace = seen["trace"]
    assert trace["truth_t"][-1] == end_t
    assert trace["truth"][-1] == episode["final_p_dlo_m"]
    assert np.linalg.norm(np.subtract(trace["truth"][-1], trace["goal"])) == metrics["final_distance_m"]

    # The video: a frame at the start of every 40 ms period and one at the outcome.
    frames = read_video(out / "demo.mp4")
    assert len(frames) == len(seen["frames"]) == metrics["video"]["frames"] == metrics["cycles"] + 1
    assert len(frames) == round(end_t / PERIOD_S) + 1
    # Its last frame draws the true tip where metrics.json has it (the camera does not move).
    env = gym.make("DynDLO/TipControl-v0", multi_step=True)
    env.reset(seed=100000)
    with MujocoCamera(env.unwrapped.model, env.unwrapped.data, "tracking") as camera:
        expected = camera.calibration.project(np.asarray([episode["final_p_dlo_m"]]))[0]
    assert np.linalg.norm(true_tip_marker_px(seen["frames"][-1]) - expected) < 1.5
    plot = cv2.imread(str(out / "p_dlo.png"))
    assert plot is not None and plot.shape[0] > 300


@pytest.mark.slow
def test_demo_episodes_aggregate_and_a_full_length_miss_is_filmed_to_its_outcome(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``--episodes 2``: top-level numbers are the run's, rows per episode; episode 0 misses and runs long.

    Seed 100175 misses and runs all 40 decisions (the first of the shipped policy's full-length misses in
    seeds 100000-100299); the environment then follows the last plan for the 0.5 s settle time before it
    scores the episode, and the video and plot go on through that time.
    """
    seen = spy_outputs(monkeypatch)
    out = tmp_path / "demo"
    argv = ["demo", "--out", str(out), "--observation", "true", "--seed", "100175", "--episodes", "2"]
    assert main([*argv, "--quiet"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    rows = metrics["episodes"]
    assert [r["seed"] for r in rows] == [100175, 100176]
    assert [r["success"] for r in rows] == [False, True]
    assert metrics["num_episodes"] == 2 and metrics["successes"] == 1 and metrics["success_rate"] == 0.5
    assert metrics["success_ci95"] == list(wilson_interval(1, 2))
    for key in ("final_distance_m", "min_distance_m"):
        assert metrics[f"{key}_median"] == pytest.approx(np.median([r[key] for r in rows]))
    assert metrics["cycles"] == sum(r["cycles"] for r in rows)
    assert "success" not in metrics and "final_distance_m" not in metrics  # no episode's numbers on top

    miss = rows[0]
    assert miss["stop_reason"] == "duration" and miss["cycles"] == 40
    end_t = miss["end_time_s"]
    task = TipControl(multi_step=True)
    assert end_t == pytest.approx(task.episode_s + task.settle_s)
    trace = seen["trace"]
    # Truth every 40 ms through the settle time, then at the outcome (2.10 s, half a period later).
    assert trace["truth_t"][:-1] == pytest.approx([PERIOD_S * k for k in range(math.ceil(end_t / PERIOD_S))])
    assert trace["truth_t"][-1] == end_t and trace["truth"][-1] == miss["final_p_dlo_m"]
    assert np.linalg.norm(np.subtract(trace["truth"][-1], trace["goal"])) == miss["final_distance_m"]
    frames = read_video(out / "demo.mp4")
    assert len(frames) == len(trace["truth_t"]) == math.ceil(end_t / PERIOD_S) + 1 == 54


# ---------------------------------------------------------------- fast: the command around the episodes


NAMED_RGB = {"cyan": (0, 255, 255), "magenta": (255, 0, 255), "white": (255, 255, 255),
             "yellow": (255, 255, 0), "red": (255, 0, 0), "green": (0, 255, 0), "blue": (0, 0, 255),
             "black": (0, 0, 0)}


def test_overlay_colours_are_the_legends_and_stand_apart_from_the_scene() -> None:
    """The true P_DLO used to be drawn green, the colour the scene renders the target sphere in."""
    import gymnasium as gym

    import dyndlo_vision  # noqa: F401
    from dyndlo_vision.sim.cable_look import CableLook
    from dyndlo_vision.tracking import annotate

    # The tracker's drawing is what the legend says it is.
    assert demo.CABLE_RGB == annotate._LINE_RGB and demo.ESTIMATE_RGB == annotate._POINT_RGB
    for text, rgb in (*demo.LEGEND, *demo.LEGEND_UNTRACKED):
        name = text.split()[0].rstrip(":")
        assert min(NAMED_RGB, key=lambda n: np.linalg.norm(np.subtract(NAMED_RGB[n], rgb))) == name, text
    model = gym.make("DynDLO/TipControl-v0", multi_step=True).unwrapped.model
    cable_rgb = 255 * CableLook.of(model).rgba(model)[:3]
    scene = {"target sphere": 255 * model.geom("target_geom").rgba[:3], "cable": cable_rgb}
    overlay = {"true P_DLO": demo.TRUE_RGB, "target ring": demo.TARGET_RGB, "tracked cable": demo.CABLE_RGB,
               "estimate": demo.ESTIMATE_RGB}
    for name, rgb in overlay.items():
        for other, other_rgb in (*scene.items(), *((k, v) for k, v in overlay.items() if k != name)):
            assert np.linalg.norm(np.subtract(rgb, other_rgb)) > 100, f"{name} {rgb} looks like {other}"


def fake_record(seed: int, success: bool, cycle_ms: list[float]) -> dict[str, Any]:
    """What ``run_episode`` returns, made up: a hit ends 1 cm from the target, a miss 20 cm."""
    distance = 0.01 if success else 0.2
    goal = [0.8, 0.0, 0.4]
    tip = [0.8 + distance, 0.0, 0.4]
    return {
        "seed": seed, "success": success, "final_distance_m": distance, "final_p_dlo_m": tip,
        "end_time_s": 0.08, "min_distance_m": distance / 2, "estimate_rmse_m": 0.001 * (seed % 7),
        "cycle_ms_p50": float(np.percentile(cycle_ms, 50)),
        "cycle_ms_p95": float(np.percentile(cycle_ms, 95)),
        "stage_ms_p50": {}, "stage_ms_p95": {}, "deadline_misses": 1, "cycles": len(cycle_ms),
        "stop_reason": "done" if success else "duration", "avoid": {},
        "trace": {"t": [0.0, 0.04], "estimate": [tip, tip], "measured": [True, False],
                  "truth_t": [0.0, 0.04, 0.08], "truth": [tip, tip, tip], "goal": goal,
                  "success_radius_m": 0.035, "replan_end_t": 0.08, "success": success,
                  "min_distance_m": distance / 2},
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
    monkeypatch.setattr(demo, "film_episode", run_episode)
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


def test_summarize_counts_clean_successes_and_each_avoid_condition() -> None:
    """A success whose episode met an avoid condition (a vault with the TCP over v_max) is a success but not a
    clean one; a failure with one is neither; every condition is counted once per episode that met it."""
    records = [fake_record(k, ok, [1.0]) for k, ok in enumerate((True, True, False, True))]
    records[1]["avoid"] = {"velocity": True, "collision": False}
    records[2]["avoid"] = {"velocity": True, "torn": True}
    records[3]["avoid"] = {"velocity": False}
    metrics = demo.summarize(records)
    assert metrics["successes"] == 3 and metrics["clean_successes"] == 2
    assert metrics["clean_success_rate"] == 0.5
    assert metrics["avoid_episodes"] == {"velocity": 2, "torn": 1}


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
    metrics = json.loads((tmp_path / "a" / "metrics.json").read_text())
    assert metrics["success_rate"] == pytest.approx(2 / 3) and len(metrics["episodes"]) == 3
    assert metrics["video"]["frames"] == 3 and metrics["video"]["codec"] == "h264"
    import av  # what browsers play: H.264 in yuv420p, as PyAV reads the file back

    with av.open(str(tmp_path / "a" / "demo.mp4")) as container:
        stream = container.streams.video[0]
        assert (stream.codec_context.name, stream.codec_context.pix_fmt) == ("h264", "yuv420p")
        assert sum(1 for _ in container.decode(stream)) == 3


def test_demo_rejects_bad_input_and_writes_nothing(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    for argv in (
        ["--episodes", "0"],
        ["--policy", str(tmp_path / "missing.zip")],
        ["--latency-ms", "-5"],
        ["--latency-ms", "nan"],
        ["--latency-ms", "300"],
        ["--latency-ms", "40", "--observation", "true"],
        ["--views", "2"],  # tip control's scene has one tracking camera
        ["--views", "3"],
        ["--views", "2", "--task", "vaulting", "--observation", "true"],
        ["--raw-videos", "--observation", "true"],
        ["--raw-videos", "--latency-ms", "40"],
        ["--obs-noise", "packaged"],  # the default observation is tracked
        ["--observation", "noisy", "--obs-noise", str(tmp_path / "missing.json")],
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
    def broken_plot(path: Path, trace: dict[str, Any], *args: Any) -> None:
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
@pytest.mark.parametrize("seed", [100000, 100175])
def test_demo_loop_on_true_state_is_the_environment_episode(seed: int) -> None:
    """The demo's loop on true state scores a multi-step episode exactly as ``env.step`` does.

    Seed 100175 misses and runs all 40 decisions: after the last re-plan the environment follows that plan for
    the settle time, and so must the loop (holding the TCP instead once changed the outcome of this seed; the
    loop sends it one period at a time, for the video, and must still end in the environment's state).
    """
    import gymnasium as gym

    from dyndlo_vision import policies
    from dyndlo_vision.commands.demo import film_episode
    from dyndlo_vision.policies.actor import deterministic_policy

    env = gym.make("DynDLO/TipControl-v0", multi_step=True)
    model = policies.load("tip-control-multi-step", env=env)
    # The loop's own forward pass (equal to predict within float rounding: test_policy_actor.py), so that
    # the episodes agree to the last bit and this compares the loop's scoring with the environment's.
    act = deterministic_policy(model)
    obs, _ = env.reset(seed=seed)
    done, steps = False, 0
    while not done:
        obs, _, done, _, info = env.step(act(obs))
        steps += 1
    end_time = env.unwrapped.scene.time
    end_tip = env.unwrapped.p_dlo()
    if seed == 100175:
        assert steps == 40 and not info["is_success"]  # the full-length miss this case is about
    record = film_episode(env, model, seed, "true", "tracking", None)
    assert record["cycles"] == steps
    assert record["success"] == info["is_success"] and record["avoid"] == info["avoid"]
    assert record["min_distance_m"] == pytest.approx(info["min_distance_m"], abs=1e-9)
    assert env.unwrapped.scene.time == pytest.approx(end_time)
    assert record["end_time_s"] == pytest.approx(end_time)
    assert record["final_p_dlo_m"] == pytest.approx(end_tip.tolist(), abs=1e-9)
    assert np.isfinite(record["final_distance_m"])


def test_the_status_line_tells_measured_continued_predicted_and_lost_apart() -> None:
    from types import SimpleNamespace

    from dyndlo_vision.commands.demo import estimate_state

    def cycle(measured: bool, lost: bool = False, continued: bool = False) -> SimpleNamespace:
        return SimpleNamespace(measured=measured, lost=lost, continued=continued)

    assert estimate_state(cycle(True)) == "measured"
    assert estimate_state(cycle(True, continued=True)) == "measured, continued"
    assert estimate_state(cycle(False)) == "predicted"
    assert estimate_state(cycle(False, lost=True)) == "lost"
    assert estimate_state(cycle(True, lost=True)) == "lost"  # a lost source's reading is not an estimate


# ---------------------------------------------------------------- issue 16: randomised cables, frozen P_DLO


def test_frozen_observation_gives_the_policy_p_dlo_as_at_reset() -> None:
    """``frozen`` hands the policy the reset P_DLO in every cycle while the cable moves; ``true`` does not."""
    import gymnasium as gym

    from dyndlo_vision.control.episode import run_loop_episode
    from dyndlo_vision.tasks.baselines import RandomActions

    env = gym.make("DynDLO/TipControl-v0", multi_step=True)
    seen: dict[str, list[np.ndarray]] = {"frozen": [], "true": []}
    for observation, observations in seen.items():
        actions = RandomActions(env, seed=3)

        def act(obs: np.ndarray, observations: list[np.ndarray] = observations,
                actions: RandomActions = actions) -> np.ndarray:
            observations.append(obs[6:9].copy())  # table II: TCP position, velocity, then P_DLO
            return actions(obs)

        record = run_loop_episode(env, act, 100000, observation)
        assert record["cycles"] == len(observations) > 3
    env.reset(seed=100000)
    at_reset = env.unwrapped.p_dlo().astype(np.float32)
    np.testing.assert_array_equal(np.array(seen["frozen"]), np.tile(at_reset, (len(seen["frozen"]), 1)))
    true = np.array(seen["true"])
    np.testing.assert_array_equal(true[0], at_reset)
    assert np.linalg.norm(true - at_reset, axis=1).max() > 0.05  # the cable moved, and true state shows it


def test_noisy_observation_reads_p_dlo_through_the_noise_model_given(tmp_path: Path) -> None:
    """``demo --observation noisy --obs-noise MODEL.json``: the loop's P_DLO error is the given model's (a
    2 cm model gives about 2 cm per axis, a 0.2 mm one about 0.2 mm), and metrics.json names the model."""
    from dataclasses import replace

    import gymnasium as gym

    from dyndlo_vision.control.episode import run_loop_episode
    from dyndlo_vision.tasks.baselines import RandomActions
    from dyndlo_vision.tasks.noise import ObservationNoiseModel, packaged_noise_model_path

    packaged = ObservationNoiseModel.load(packaged_noise_model_path())
    env = gym.make("DynDLO/TipControl-v0", multi_step=True)
    per_axis = {}
    for std in (0.02, 2e-4):
        model = replace(packaged, bias_m=(0.0, 0.0, 0.0), std_m=(std, std, std), std_per_speed_s=0.0,
                        dropout_prob=0.0)
        record = run_loop_episode(env, RandomActions(env, seed=3), 100000, "noisy", noise_model=model)
        per_axis[std] = record["estimate_rmse_m"] / np.sqrt(3)
    assert 0.6 * 0.02 < per_axis[0.02] < 1.4 * 0.02 and 0.6 * 2e-4 < per_axis[2e-4] < 1.4 * 2e-4
    with pytest.raises(ValueError, match="noisy observation"):
        run_loop_episode(env, RandomActions(env, seed=3), 100000, "true", noise_model=model)

    path = tmp_path / "model.json"
    model.save(path)
    out = tmp_path / "run"
    argv = ["demo", "--observation", "noisy", "--obs-noise", str(path), "--out", str(out), "--quiet"]
    assert main(argv) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["obs_noise"] == str(path) and metrics["estimate_rmse_m_median"] < 1e-3


@pytest.mark.slow
def test_the_noisy_observation_defaults_to_the_tasks_own_tracker(tmp_path: Path) -> None:
    """Without --obs-noise the noisy row draws P_DLO through the task's own loop tracker's model: the vault's
    two-camera fit (about 1 mm per axis: under 3 mm RMSE in 3D) for vaulting, not tip control's one-camera
    fit (about 4 mm per axis: above 4 mm); metrics.json names the model."""
    rmse = {}
    for name, extra in (("vaulting-two-cameras", []), ("packaged", ["--obs-noise", "packaged"])):
        out = tmp_path / name
        argv = ["demo", "--task", "vaulting", "--policy", "vaulting-multi-step", "--observation", "noisy",
                *extra, "--out", str(out), "--quiet"]
        assert main(argv) == 0
        metrics = json.loads((out / "metrics.json").read_text())
        assert metrics["obs_noise"] == name
        rmse[name] = metrics["estimate_rmse_m_median"]
    assert rmse["vaulting-two-cameras"] < 3e-3 and rmse["packaged"] > 4e-3


@pytest.mark.slow
def test_demo_randomize_cable_draws_each_episode_cable_from_its_seed(tmp_path: Path) -> None:
    """Episode k's cable is the one ``CableRandomization`` draws for seed S + k (as ``evaluate
    --randomize-cable``), recorded in metrics.json, and the same command draws the same cables."""
    from dataclasses import asdict

    from dyndlo_vision.tasks import make_env

    argv = ["demo", "--observation", "true", "--randomize-cable", "--episodes", "2", "--seed", "500",
            "--quiet"]
    rows = []
    for run in ("a", "b"):
        assert main([*argv, "--out", str(tmp_path / run)]) == 0
        metrics = json.loads((tmp_path / run / "metrics.json").read_text())
        assert metrics["randomize_cable"] is True
        rows.append([r["cable"] for r in metrics["episodes"]])
    assert rows[0] == rows[1]
    env = make_env("tip-control", multi_step=True, randomize_cable_every=1)
    nominal = asdict(env.unwrapped.task.cable)
    for k, cable in enumerate(rows[0]):
        _, info = env.reset(seed=500 + k)
        drawn = asdict(info["cable"])
        assert cable == pytest.approx({name: drawn[name] for name in cable})
        assert cable != pytest.approx({name: nominal[name] for name in cable})
    assert rows[0][0] != rows[0][1]


def test_demo_cable_ranges_beyond_training_draw_from_the_wider_ranges(tmp_path: Path) -> None:
    from dataclasses import asdict

    from dyndlo_vision.tasks import make_env
    from dyndlo_vision.tasks.wrappers import BEYOND_TRAINING_CABLE_RANGES, DEFAULT_CABLE_RANGES

    for name, (lo, hi) in BEYOND_TRAINING_CABLE_RANGES.items():  # wider than training on every side
        assert lo < DEFAULT_CABLE_RANGES[name][0] and hi > DEFAULT_CABLE_RANGES[name][1]
    out = tmp_path / "beyond"
    argv = ["demo", "--observation", "true", "--randomize-cable", "--cable-ranges", "beyond", "--seed", "9"]
    assert main([*argv, "--quiet", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["cable_ranges"] == "beyond"
    env = make_env("tip-control", multi_step=True, randomize_cable_every=1,
                   cable_ranges=BEYOND_TRAINING_CABLE_RANGES)
    _, info = env.reset(seed=9)
    drawn = asdict(info["cable"])
    cable = metrics["episodes"][0]["cable"]
    assert cable == pytest.approx({k: drawn[k] for k in cable})
    # --cable-ranges alone draws the same cables (as in distill, train and evaluate): it means random cables.
    alone = tmp_path / "alone"
    argv = ["demo", "--observation", "true", "--cable-ranges", "beyond", "--seed", "9"]
    assert main([*argv, "--quiet", "--out", str(alone)]) == 0
    again = json.loads((alone / "metrics.json").read_text())
    assert again["randomize_cable"] is True and again["cable_ranges"] == "beyond"
    assert again["episodes"][0]["cable"] == cable


@pytest.mark.slow
def test_demo_vaulting_tracks_the_cables_middle_from_a_camera_that_sees_the_scene(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`demo --task vaulting`: the shipped single-step vault through the loop, P_DLO (the cable's middle)
    tracked from the vaulting scene's own camera, which sees the cable from the TCP to the support."""
    from dyndlo_vision.tasks.vaulting import OBSTACLE_CENTRE_M, SUPPORT_M

    seen = spy_outputs(monkeypatch)
    out = tmp_path / "demo"
    assert main(["demo", "--task", "vaulting", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["task"] == metrics["policy"] == "vaulting" and metrics["multi_step"] is False
    assert metrics["success"] is True and not any(metrics["episodes"][0]["avoid"].values())
    # Tracked for the whole episode (the loop reads the camera every cycle while the plan runs): the middle
    # is measured in every cycle, 51 mm RMSE on this seed (the cable swings up to 11 cm off the plane the
    # tracker lifts onto), and at the start it lies on the floor beside the box, where the floor puts it.
    trace = seen["trace"]
    assert all(trace["measured"]) and len(trace["t"]) == metrics["cycles"] > 40
    assert 0.0 < metrics["estimate_rmse_m"] < 0.08
    start_est, start_true = np.array(trace["estimate"][0]), np.array(trace["truth"][0])
    assert start_true[1] < -0.1 and np.linalg.norm(start_est - start_true) < 0.05  # measured 32 mm
    end_est, end_true = np.array(trace["estimate"][-1]), np.array(trace["truth"][-1])
    assert np.linalg.norm(end_est - end_true) < 0.02  # landed beyond the box, in the plane: measured 4 mm
    assert trace["goal"] == list(OBSTACLE_CENTRE_M)
    assert "Vaulting: SUCCESS" in trace["outcome"]
    # The camera sees the TCP, the box, the support, the cable's start on the floor, and the TCP up to 1 m.
    import gymnasium as gym

    from dyndlo_vision.cameras.simulated import MujocoCamera

    env = gym.make("DynDLO/Vaulting-v0")
    env.reset(seed=100000)
    with MujocoCamera(env.unwrapped.model, env.unwrapped.data, "tracking") as camera:
        uv = camera.calibration.project(np.array([[0.40, 0.0, 0.20], OBSTACLE_CENTRE_M, SUPPORT_M,
                                                  [0.40, -0.164, 0.0], [0.40, 0.0, 1.0]]))
    assert np.all((uv > 20) & (uv < [620, 460]))
    assert len(read_video(out / "demo.mp4")) == metrics["video"]["frames"] == metrics["cycles"] + 1


@pytest.mark.slow
def test_demo_vaulting_rejects_a_mismatched_policy(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "demo"
    for argv, message in (
        (["--task", "vaulting", "--policy", "tip-control-multi-step"],
         "is for tip-control, not --task vaulting"),
    ):
        with pytest.raises(SystemExit) as exc:
            main(["demo", "--out", str(out), *argv])
        assert exc.value.code == 2
        assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_vaulting_draws_beyond_the_training_ranges_only_with_cables_that_fit_its_scene() -> None:
    from dyndlo_vision.tasks.vaulting import check_cable_lengths, shortest_cable_m
    from dyndlo_vision.tasks.wrappers import BEYOND_TRAINING_CABLE_RANGES, cable_ranges_for

    assert cable_ranges_for("tip-control", "beyond") == BEYOND_TRAINING_CABLE_RANGES
    vaulting = cable_ranges_for("vaulting", "beyond")
    assert vaulting["length_m"] == (0.9, 1.2)  # 0.8x would be 0.72 m, under the 0.807 m that fit
    assert {k: v for k, v in vaulting.items() if k != "length_m"} == {
        k: v for k, v in BEYOND_TRAINING_CABLE_RANGES.items() if k != "length_m"}
    assert 0.9 * 0.9 >= shortest_cable_m() > 0.8 * 0.9
    check_cable_lengths(vaulting["length_m"][0], "beyond")
    too_short = "down to 0.8 x 0.9 m = 0.720 m, but the vaulting scene needs at least 0.807 m"
    with pytest.raises(ValueError, match=too_short):
        check_cable_lengths(0.8, "--cable-ranges beyond")
    with pytest.raises(ValueError, match="cable ranges 'wider'; expected one of"):
        cable_ranges_for("vaulting", "wider")


def test_demo_starts_a_history_policy_afresh_in_every_episode(tmp_path: Path) -> None:
    """A policy with a P_DLO history (``p_dlo_history`` in its JSON) runs in the demo; each episode forgets
    the last one, so an episode scores the same whether another ran before it or not."""
    import gymnasium as gym

    from dyndlo_vision import policies
    from dyndlo_vision.commands.demo import film_episode
    from dyndlo_vision.learning.distill import new_student
    from dyndlo_vision.tasks.wrappers import PDloHistoryWrapper

    env = gym.make("DynDLO/TipControl-v0", multi_step=True)
    zip_file = tmp_path / "history.zip"
    new_student(PDloHistoryWrapper(env, 2), (16,), seed=3).save(zip_file)
    zip_file.with_suffix(".json").write_text(json.dumps(
        {"task": "tip-control", "multi_step": True, "algo": "ppo", "p_dlo_history": 2}
    ))
    model = policies.load(zip_file, env=env)
    film_episode(env, model, 11, "true", "tracking", None)
    after = film_episode(env, model, 12, "true", "tracking", None)
    alone = film_episode(env, policies.load(zip_file, env=env), 12, "true", "tracking", None)
    assert after["final_p_dlo_m"] == pytest.approx(alone["final_p_dlo_m"], abs=1e-12)
    env.close()
    out = tmp_path / "demo"
    argv = ["demo", "--policy", str(zip_file), "--observation", "tracked", "--quiet", "--out", str(out)]
    assert main(argv) == 0
    assert json.loads((out / "metrics.json").read_text())["episodes"][0]["cycles"] > 1


def test_the_second_cameras_view_is_inset_top_right_with_its_cable_and_the_estimate() -> None:
    from types import SimpleNamespace

    from dyndlo_vision.control.episode import SecondView
    from tests.tracking.helpers import look_at_camera

    calib = look_at_camera(eye=(1.3, -0.9, 1.8), target=(0.7, 0.0, 0.35))
    estimate = np.array([0.7, 0.0, 0.35])  # the image centre
    polyline = np.array([[100.0, 100.0], [500.0, 400.0], [np.nan, np.nan]])
    view = SecondView(np.full((480, 640, 3), 128, np.uint8), polyline, calib)
    frame = np.zeros((480, 640, 3), np.uint8)
    demo._draw_second_view(frame, view, SimpleNamespace(p_dlo_true=None, p_dlo_estimate=estimate))
    inset = frame[:160, 640 - 213:]
    assert np.all(frame[170:, :] == 0) and np.all(frame[:, :400] == 0)  # only the corner is drawn on
    cyan_bgr = np.array(demo.CABLE_RGB[::-1])
    magenta_bgr = np.array(demo.ESTIMATE_RGB[::-1])
    assert np.any(np.all(np.abs(inset.astype(int) - cyan_bgr) < 40, axis=2))
    centre = inset[70:90, 96:116].astype(int)  # the estimate, drawn at the image centre, scaled by a third
    assert np.any(np.all(np.abs(centre - magenta_bgr) < 60, axis=2))


def _track_errors(csv_path: Path, truth_path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The unfiltered measured point's distance to the truth (m); and the visible flags."""
    import csv

    with open(csv_path, newline="") as f:
        rows = list(csv.DictReader(f))
    with open(truth_path, newline="") as f:
        truth = list(csv.DictReader(f))
    assert len(rows) == len(truth)
    seen = np.array([r["visible"] == "1" for r in rows])
    meas = np.array([[float(r[c]) if r[c] else np.nan for c in ("x_meas", "y_meas", "z_meas")] for r in rows])
    true = np.array([[float(t[c]) for c in "xyz"] for t in truth])
    return np.linalg.norm(meas[seen] - true[seen], axis=1), seen


@pytest.mark.slow
def test_raw_videos_are_what_track_reads_and_match_the_truth(tmp_path: Path) -> None:
    """``demo --raw-videos`` writes the loop camera's frames, its calibration, the TCP and the true P_DLO per
    frame. ``track`` on them, as a user would run it with the cable's length, finds the truth: tip control's
    tip on the plane; the vault's middle with two cameras. Measured: tip 2.8 mm median over 17 frames
    (60.8 mm at most, one frame); the vault's middle 2.0 mm median, 3.6 at most. The frames must be the ones
    rendered where the truth was read: the present, a period later, put a vault's middle 17 mm off."""
    out = tmp_path / "tip"
    assert main(["demo", "--raw-videos", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    n = metrics["video"]["frames"]
    assert metrics["raw_videos"]["frames"] == n
    assert len(list((out / "raw").iterdir())) == n and not (out / "raw2").exists()
    tip_length = metrics["episodes"][0]["cable"]["length_m"]
    assert main(["track", str(out / "raw"), "--fps", "25", "--calib", str(out / "camera.json"), "--plane",
                 "0,1,0,0", "--tcp-log", str(out / "tcp.csv"), "--cable-length", str(tip_length),
                 "--out", str(tmp_path / "tip.csv"), "--quiet"]) == 0
    err, seen = _track_errors(tmp_path / "tip.csv", out / "truth.csv")
    assert seen.mean() > 0.8 and np.median(err) < 0.005, (seen.mean(), err)

    vault = tmp_path / "vault"
    assert main(["demo", "--task", "vaulting", "--raw-videos", "--out", str(vault)]) == 0
    length = json.loads((vault / "metrics.json").read_text())["episodes"][0]["cable"]["length_m"]
    assert len(list((vault / "raw2").iterdir())) == len(list((vault / "raw").iterdir()))
    assert main(["track", str(vault / "raw"), "--fps", "25", "--calib", str(vault / "camera.json"),
                 "--second-video", str(vault / "raw2"), "--second-calib", str(vault / "camera2.json"),
                 "--tcp-log", str(vault / "tcp.csv"), "--point", "0.5", "--cable-length", str(length),
                 "--out", str(tmp_path / "vault.csv"), "--quiet"]) == 0
    err, seen = _track_errors(tmp_path / "vault.csv", vault / "truth.csv")
    assert seen.mean() > 0.8 and np.median(err) < 0.004 and err.max() < 0.01, (seen.mean(), err)



def test_the_plot_does_not_draw_a_still_coordinate_on_rounding_noise(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """y stays in the motion plane up to 1e-17 m: its panel spans 5 cm about it, not the noise; a coordinate
    that moves keeps its own range."""
    import matplotlib.pyplot as plt

    t = np.arange(6) * PERIOD_S
    still_y = 1e-17 * np.sin(np.arange(6))
    truth = np.column_stack([np.linspace(0.4, 0.8, 6), still_y, np.linspace(0.1, 0.5, 6)])
    trace = {"t": t, "estimate": truth, "measured": np.ones(6, bool), "truth_t": t, "truth": truth,
             "goal": np.array([0.7, 0.0, 0.5]), "replan_end_t": t[-1], "success": True,
             "success_radius_m": 0.035, "min_distance_m": 0.1}
    figures = []
    close = plt.close
    monkeypatch.setattr(plt, "close", lambda fig=None: (figures.append(fig), close(fig)))
    demo._write_plot(tmp_path / "p.png", trace)
    assert (tmp_path / "p.png").is_file()
    x_ax, y_ax = figures[0].axes[:2]
    lo, hi = y_ax.get_ylim()
    assert hi - lo == pytest.approx(0.05) and lo < 0.0 < hi
    assert x_ax.get_ylim()[1] - x_ax.get_ylim()[0] > 0.4
    assert demo._widened(0.2, 0.3, 0.05) == (0.2, 0.3)
