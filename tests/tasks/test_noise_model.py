"""Tests of the observation-noise model (fit, files) and of the NoisyObservation wrapper."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import dyndlo_vision  # noqa: F401  (registers the environment ids)
from dyndlo_vision.tasks.noise import (
    ObservationNoiseModel,
    dropout_runs,
    packaged_noise_model_path,
    shipped_noise_model_path,
)
from dyndlo_vision.tasks.wrappers import NoisyObservation

DT = 0.04


# ---------------------------------------------------------------------------- synthetic records
def markov_dropouts(rng: np.random.Generator, n: int, p: float, run: float) -> np.ndarray:
    """Two-state chain with stationary probability p and mean run length ``run`` (first step observed)."""
    enter, leave = p / (run * (1 - p)), 1 / run
    out = np.zeros(n, dtype=bool)
    for i in range(1, n):
        out[i] = (rng.random() >= leave) if out[i - 1] else (rng.random() < enter)
    return out


def synthetic_records(
    rng: np.random.Generator,
    bias: np.ndarray,
    std0: np.ndarray,
    gain: float,
    latency: float,
    p_drop: float,
    run: float,
    episodes: int = 40,
    steps: int = 500,
) -> dict[str, np.ndarray]:
    """Slow sinusoids (0.15-0.3 Hz, 0.3 m), estimate = truth(t - latency) + bias + noise, Markov dropouts.

    The motion is slow enough that the first-order expansion the fit uses is exact to 0.6 mm at 40 ms.
    """
    t = np.arange(steps) * DT
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("truth", "estimate", "velocity", "episode", "sigma")}
    for e in range(episodes):
        w = rng.uniform(0.15, 0.3, 3) * 2 * np.pi
        phase = rng.uniform(0, 2 * np.pi, 3)
        amp = np.array([0.3, 0.3, 0.3])
        truth = amp * np.sin(w * t[:, None] + phase)
        vel = amp * w * np.cos(w * t[:, None] + phase)
        delayed = amp * np.sin(w * (t[:, None] - latency) + phase)
        speed = np.linalg.norm(vel, axis=1)
        sigma = std0 + gain * speed[:, None]
        est = delayed + bias + sigma * rng.standard_normal((steps, 3))
        est[markov_dropouts(rng, steps, p_drop, run)] = np.nan
        for key, value in (("truth", truth), ("estimate", est), ("velocity", vel), ("sigma", sigma)):
            out[key].append(value)
        out["episode"].append(np.full(steps, e))
    return {k: np.concatenate(v) for k, v in out.items()}


def test_fit_recovers_known_parameters_within_sampling_error() -> None:
    rng = np.random.default_rng(7)
    bias, std0, gain, latency, p_drop, run = (
        np.array([0.004, -0.002, 0.006]),
        np.array([0.005, 0.002, 0.008]),
        0.004,
        0.05,
        0.15,
        2.5,
    )
    rec = synthetic_records(rng, bias, std0, gain, latency, p_drop, run)
    model = ObservationNoiseModel.fit(rec["truth"], rec["estimate"], rec["velocity"], episode=rec["episode"])
    obs = np.all(np.isfinite(rec["estimate"]), axis=1)
    sig, vel = rec["sigma"][obs], rec["velocity"][obs]
    n = int(obs.sum())
    # Bias and latency: standard errors of the least-squares fit with these noise levels.
    se_bias = np.sqrt(np.mean(sig**2, axis=0) / n)
    se_latency = math.sqrt(float(np.sum(sig**2 * vel**2))) / float(np.sum(vel**2))
    np.testing.assert_allclose(model.bias_m, bias, atol=5 * se_bias.max())
    assert model.latency_s == pytest.approx(latency, abs=5 * se_latency)
    # Standard deviation: OLS of sqrt(pi/2)|r| on [axis one-hot, speed], whose per-sample variance is
    # sigma^2 (pi/2 - 1); plus 1 % for the second-order term of the delayed sinusoid.
    speed = np.linalg.norm(vel, axis=1)
    design = np.zeros((3 * n, 4))
    for a in range(3):
        design[a::3, a] = 1.0
    design[:, 3] = np.repeat(speed, 3)
    inv = np.linalg.inv(design.T @ design)
    var_y = (sig**2).reshape(-1) * (math.pi / 2 - 1)
    cov = inv @ (design.T * var_y) @ design @ inv
    se = np.sqrt(np.diag(cov))
    np.testing.assert_allclose(model.std_m, std0, atol=5 * se[:3].max() + 0.01 * std0.max())
    assert model.std_per_speed_s == pytest.approx(gain, abs=5 * se[3] + 0.01 * gain)
    # Dropouts: binomial error inflated by the chain's autocorrelation; run length: geometric runs.
    enter, leave = p_drop / (run * (1 - p_drop)), 1 / run
    rho = 1 - enter - leave
    k = rec["estimate"].shape[0]
    se_p = math.sqrt(p_drop * (1 - p_drop) / k * (1 + rho) / (1 - rho))
    assert model.dropout_prob == pytest.approx(p_drop, abs=5 * se_p)
    n_runs = len(dropout_runs(~obs, rec["episode"]))
    se_run = math.sqrt((1 - leave) / leave**2 / n_runs)
    assert model.dropout_mean_run == pytest.approx(run, abs=5 * se_run)
    assert model.n_samples == k


def test_fit_without_speed_dependence_gives_rms_and_clips_a_lead_to_zero_latency() -> None:
    rng = np.random.default_rng(3)
    std0 = np.array([0.004, 0.001, 0.006])
    # A negative latency is an estimate that leads the truth: clipped to 0, bias refitted without it.
    rec = synthetic_records(rng, np.zeros(3), std0, 0.0, -0.03, 0.0, 1.0, episodes=10, steps=400)
    model = ObservationNoiseModel.fit(rec["truth"], rec["estimate"], rec["velocity"], speed_dependent=False)
    assert model.latency_s == 0.0 and model.std_per_speed_s == 0.0
    assert model.dropout_prob == 0.0 and model.dropout_mean_run == 1.0
    # With the lead left in the residual, the RMS grows by |latency| * velocity: bounded from below by std0.
    assert np.all(np.asarray(model.std_m) >= std0 * 0.97)


def test_fit_rejects_bad_records() -> None:
    truth = np.zeros((20, 3))
    with pytest.raises(ValueError, match="same K"):
        ObservationNoiseModel.fit(truth, np.zeros((19, 3)), np.zeros((20, 3)))
    with pytest.raises(ValueError, match="at least 10"):
        est = np.full((20, 3), np.nan)
        est[:5] = 0.0
        ObservationNoiseModel.fit(truth, est, np.zeros((20, 3)))
    with pytest.raises(ValueError, match="truth must be finite"):
        bad = truth.copy()
        bad[3, 1] = np.nan
        ObservationNoiseModel.fit(bad, np.zeros((20, 3)), np.zeros((20, 3)))


def test_dropout_runs_do_not_span_episodes() -> None:
    dropped = [True, True, False, True, True, True, False, True]
    assert dropout_runs(dropped) == [2, 3, 1]
    assert dropout_runs(dropped, episode=[0, 0, 0, 0, 1, 1, 1, 1]) == [2, 1, 2, 1]


# ---------------------------------------------------------------------------- files
def full_model(**overrides: Any) -> ObservationNoiseModel:
    values: dict[str, Any] = {
        "bias_m": (0.002, 0.0, -0.004),
        "std_m": (0.006, 0.0005, 0.008),
        "std_per_speed_s": 0.003,
        "latency_s": 0.012,
        "dropout_prob": 0.1,
        "dropout_mean_run": 2.0,
        "max_coast_steps": 7,
        "n_samples": 1234,
        "source": "test",
        "tcp_position_std_m": 3e-4,
        "tcp_velocity_std_m_s": 4e-3,
    }
    values.update(overrides)
    return ObservationNoiseModel(**values)


def test_save_load_round_trip(tmp_path: Path) -> None:
    model = full_model()
    path = tmp_path / "model.json"
    model.save(path)
    data = json.loads(path.read_text())
    assert data["format"] == "dyndlo_vision.observation_noise" and data["version"] == 2
    loaded = ObservationNoiseModel.load(path)
    assert loaded == model and loaded.source == "test"
    assert [p.name for p in tmp_path.iterdir()] == ["model.json"]  # no temporary file left behind


@pytest.mark.parametrize(
    "content,match",
    [
        ("{not json", "not valid JSON"),
        ("[1, 2]", "expected a JSON object"),
        ('{"format": "something else", "version": 1}', "format is 'something else'"),
        ('{"format": "dyndlo_vision.observation_noise", "version": 99}', "version 99 is not supported"),
    ],
)
def test_bad_files_give_clear_errors(tmp_path: Path, content: str, match: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=match) as info:
        ObservationNoiseModel.load(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    "edit,match",
    [
        (lambda d: d.pop("latency_s"), r"missing key\(s\) \['latency_s'\]"),
        (lambda d: d.update(colour="red"), r"unknown key\(s\) \['colour'\]"),
        (lambda d: d.update(std_m=[0.01, -0.01, 0.0]), "std_m must be >= 0"),
        (lambda d: d.update(bias_m=[0.0, 0.0]), "bias_m must be 3 finite numbers"),
        (lambda d: d.update(dropout_prob=1.0), r"dropout_prob must be in \[0, 1\)"),
        (lambda d: d.update(dropout_prob=0.9, dropout_mean_run=2.0), "impossible"),
        (lambda d: d.update(latency_s="40 ms"), "latency_s must be a number"),
        (lambda d: d.update(tcp_position_std_m=-1e-4), r"tcp_position_std_m must be in \[0, 10\]"),
        (lambda d: d.pop("tcp_velocity_std_m_s"), r"missing key\(s\) \['tcp_velocity_std_m_s'\]"),
        (lambda d: d.update(version=1), r"unknown key\(s\) \['tcp_position_std_m', 'tcp_velocity_std_m_s'\]"),
    ],
)
def test_bad_values_give_clear_errors(tmp_path: Path, edit: Any, match: str) -> None:
    data = full_model().to_dict()
    edit(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=match):
        ObservationNoiseModel.load(path)


def test_a_version_1_file_reads_with_no_tcp_noise(tmp_path: Path) -> None:
    """Files written before the TCP noise existed (version 1, without its keys) still load, and mean none."""
    data = full_model().to_dict()
    for key in ("tcp_position_std_m", "tcp_velocity_std_m_s"):
        data.pop(key)
    data["version"] = 1
    path = tmp_path / "old.json"
    path.write_text(json.dumps(data))
    loaded = ObservationNoiseModel.load(path)
    assert loaded == full_model(tcp_position_std_m=0.0, tcp_velocity_std_m_s=0.0)


def test_fit_stores_the_default_tcp_noise_and_the_identity_needs_none() -> None:
    from dyndlo_vision.tasks.noise import DEFAULT_TCP_POSITION_STD_M, DEFAULT_TCP_VELOCITY_STD_M_S

    rng = np.random.default_rng(0)
    rec = synthetic_records(rng, np.zeros(3), np.full(3, 0.002), 0.0, 0.0, 0.0, 1.0, episodes=2, steps=50)
    fitted = ObservationNoiseModel.fit(rec["truth"], rec["estimate"], rec["velocity"])
    assert (fitted.tcp_position_std_m, fitted.tcp_velocity_std_m_s) == (
        DEFAULT_TCP_POSITION_STD_M, DEFAULT_TCP_VELOCITY_STD_M_S)
    assert 0 < DEFAULT_TCP_POSITION_STD_M <= 1e-3 and 0 < DEFAULT_TCP_VELOCITY_STD_M_S <= 0.02
    assert not ObservationNoiseModel(tcp_velocity_std_m_s=1e-3).is_identity


def test_missing_file_raises_file_not_found(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        ObservationNoiseModel.load(tmp_path / "absent.json")


def test_packaged_model_loads() -> None:
    model = ObservationNoiseModel.load(packaged_noise_model_path())
    assert model.n_samples > 0 and not model.is_identity
    # The TCP state must not reach a learner exactly: the simulator's micrometre sag fingerprints the cable.
    assert model.tcp_position_std_m >= 1e-4 and model.tcp_velocity_std_m_s >= 1e-3


# ---------------------------------------------------------------------------- wrapper, fake environment
class LineEnv(gym.Env[np.ndarray, np.ndarray]):
    """DynDLO observation layout with one gripper; P_DLO at step k is ``path(k)``, nothing else moves."""

    multi_step = True

    def __init__(self, path: Any) -> None:
        self.path = path
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(12,), dtype=np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self.k = 0

    def _obs(self) -> np.ndarray:
        obs = np.zeros(12, dtype=np.float32)
        obs[6:9] = self.path(self.k)
        obs[9:] = (0.8, 0.0, 0.4)
        return obs

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.k = 0
        return self._obs(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.k += 1
        return self._obs(), 0.0, False, False, {}


def curve(k: int) -> np.ndarray:
    return np.array([0.3 * np.sin(0.2 * k), 0.0, 0.5 + 0.2 * np.cos(0.13 * k)])


def rollout(env: gym.Env, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """P_DLO as observed and as true over ``n`` steps after reset (reset included)."""
    obs, info = env.reset(seed=seed)
    seen, true = [obs[6:9]], [info["p_dlo_true"]]
    for _ in range(n):
        obs, _, _, _, info = env.step(np.zeros(1, dtype=np.float32))
        seen.append(obs[6:9])
        true.append(info["p_dlo_true"])
    return np.array(seen, dtype=np.float64), np.array(true)


def test_wrapper_noise_statistics_match_the_model() -> None:
    speed = 2.0  # m/s along x: std = std0 + gain * speed
    model = ObservationNoiseModel(bias_m=(0.01, 0.0, -0.02), std_m=(0.005, 0.0, 0.003), std_per_speed_s=0.002)
    env = NoisyObservation(LineEnv(lambda k: np.array([speed * DT * k, 0.0, 0.5])), model)
    seen, true = rollout(env, 20000)
    resid = (seen - true)[1:]  # from step 1 on the speed over the last step is 2 m/s
    expected_std = np.array([0.005, 0.0, 0.003]) + 0.002 * speed
    n = resid.shape[0]
    np.testing.assert_allclose(
        resid.mean(axis=0), model.bias_m, atol=5 * expected_std.max() / math.sqrt(n) + 1e-7
    )
    np.testing.assert_allclose(resid.std(axis=0), expected_std, rtol=5 / math.sqrt(2 * n), atol=1e-7)


def test_wrapper_tcp_noise_has_the_model_spread_and_leaves_p_dlo_numbers_alone() -> None:
    """The gripper state gets white noise of the model's spread, from its own stream: P_DLO, its noise and
    the goal are those of the same model without TCP noise, number for number."""
    base = full_model(tcp_position_std_m=0.0, tcp_velocity_std_m_s=0.0)
    with_tcp = full_model(tcp_position_std_m=3e-4, tcp_velocity_std_m_s=4e-3)

    def observations(model: ObservationNoiseModel) -> np.ndarray:
        env = NoisyObservation(LineEnv(curve), model)
        obs = [env.reset(seed=7)[0]]
        obs += [env.step(np.zeros(1, dtype=np.float32))[0] for _ in range(4000)]
        return np.array(obs, dtype=np.float64)

    plain, noisy = observations(base), observations(with_tcp)
    np.testing.assert_array_equal(noisy[:, 6:], plain[:, 6:])
    assert np.all(plain[:, :6] == 0.0)  # LineEnv's gripper rests at the origin
    n = len(noisy)
    for cols, std in ((slice(0, 3), 3e-4), (slice(3, 6), 4e-3)):
        np.testing.assert_allclose(noisy[:, cols].std(axis=0), std, rtol=5 / math.sqrt(2 * n))
        np.testing.assert_allclose(noisy[:, cols].mean(axis=0), 0.0, atol=5 * std / math.sqrt(n))
    # White: consecutive draws uncorrelated; the position and velocity noise independent.
    x = noisy[:, 0]
    assert abs(np.corrcoef(x[1:], x[:-1])[0, 1]) < 5 / math.sqrt(n)
    assert abs(np.corrcoef(noisy[:, 0], noisy[:, 3])[0, 1]) < 5 / math.sqrt(n)


def test_wrapper_dropouts_coast_at_constant_velocity_then_hold() -> None:
    model = ObservationNoiseModel(dropout_prob=0.3, dropout_mean_run=4.0, max_coast_steps=2)
    env = NoisyObservation(LineEnv(curve), model)
    seen, true = rollout(env, 20000, seed=5)
    dropped = np.any(np.abs(seen - true) > 1e-6, axis=1)  # no noise: only dropouts differ from the truth
    assert not dropped[0]
    n = dropped.size
    enter, leave = model.dropout_enter_prob, model.dropout_leave_prob
    rho = 1 - enter - leave
    se = math.sqrt(0.3 * 0.7 / n * (1 + rho) / (1 - rho))
    assert dropped.mean() == pytest.approx(0.3, abs=5 * se)
    runs = dropout_runs(dropped)
    assert np.mean(runs) == pytest.approx(4.0, abs=5 * math.sqrt((1 - leave) / leave**2 / len(runs)))
    # Inside a run: the first two steps move on by the last observed step, later steps hold.
    starts = np.flatnonzero(dropped & ~np.roll(dropped, 1))
    checked = 0
    for s in starts[starts >= 2]:
        step = seen[s - 1] - seen[s - 2]
        length = next((i for i in range(n - s) if not dropped[s + i]), n - s)
        for i in range(length):
            expected = seen[s - 1] + step * min(i + 1, 2)
            np.testing.assert_allclose(seen[s + i], expected, atol=1e-6)
            checked += 1
    assert checked > 1000


@pytest.mark.parametrize("latency_s,weights", [(0.08, {2: 1.0}), (0.06, {1: 0.5, 2: 0.5}), (0.0, {0: 1.0})])
def test_wrapper_latency_shifts_by_whole_and_fractional_steps(
    latency_s: float, weights: dict[int, float]
) -> None:
    env = NoisyObservation(LineEnv(curve), ObservationNoiseModel(latency_s=latency_s))
    seen, true = rollout(env, 30)
    for k in range(len(seen)):
        expected = sum(w * true[max(k - lag, 0)] for lag, w in weights.items())
        np.testing.assert_allclose(seen[k], expected, atol=1e-6)


def test_wrapper_rejects_other_observation_layouts() -> None:
    class Small(LineEnv):
        def __init__(self) -> None:
            super().__init__(curve)
            self.observation_space = gym.spaces.Box(-1, 1, shape=(5,), dtype=np.float32)

    with pytest.raises(ValueError, match="6 \\* n_grippers \\+ 6"):
        NoisyObservation(Small(), ObservationNoiseModel())


# ---------------------------------------------------------------------------- wrapper, real environment
def make_tip_control(model: ObservationNoiseModel | None) -> gym.Env:
    env = gym.make("DynDLO/TipControl-v0", multi_step=True).unwrapped
    return env if model is None else NoisyObservation(env, model)


def real_rollout(env: gym.Env, seed: int, n: int = 4) -> tuple[list[np.ndarray], list[np.ndarray]]:
    obs, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    observations, truths = [obs], [info.get("p_dlo_true")]
    for _ in range(n):
        obs, _, terminated, truncated, info = env.step(
            rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
        )
        observations.append(obs)
        truths.append(info.get("p_dlo_true"))
        if terminated or truncated:
            break
    return observations, truths


def test_wrapper_passes_gymnasium_check_env() -> None:
    from gymnasium.utils.env_checker import check_env

    env = make_tip_control(full_model())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unbounded boxes, and the checker's note that the env is wrapped
        check_env(env, skip_render_check=True)


def test_wrapper_is_deterministic_under_a_seed() -> None:
    a, _ = real_rollout(make_tip_control(full_model()), seed=3)
    b, _ = real_rollout(make_tip_control(full_model()), seed=3)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    env = make_tip_control(full_model(dropout_prob=0.0))
    obs1, info1 = env.reset(seed=4)
    obs2, info2 = env.reset(seed=5)
    np.testing.assert_array_equal(obs1[9:], info1["goal"].astype(np.float32))  # the target is never corrupted
    assert not np.allclose(obs1[6:9] - info1["p_dlo_true"], obs2[6:9] - info2["p_dlo_true"])


def test_zero_model_is_the_identity() -> None:
    plain, _ = real_rollout(make_tip_control(None), seed=2)
    wrapped, truths = real_rollout(make_tip_control(ObservationNoiseModel()), seed=2)
    assert len(plain) == len(wrapped) >= 3
    for x, y, t in zip(plain, wrapped, truths, strict=True):
        np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(y[6:9], t)


def test_latency_in_the_real_environment_is_whole_control_steps() -> None:
    observed, truths = real_rollout(make_tip_control(ObservationNoiseModel(latency_s=0.08)), seed=1, n=5)
    assert len(observed) >= 4
    for k in range(len(observed)):
        np.testing.assert_array_equal(observed[k][6:9], truths[max(k - 2, 0)])


def test_noise_model_paths_from_the_command_line(tmp_path) -> None:
    from dyndlo_vision.tasks.noise import resolve_noise_model_path

    assert resolve_noise_model_path(None) is None
    assert resolve_noise_model_path("packaged") == "packaged"  # the word: any install's shipped model
    ObservationNoiseModel().save(tmp_path / "m.json")
    assert resolve_noise_model_path(str(tmp_path / "m.json")) == str((tmp_path / "m.json").resolve())
    with pytest.raises(FileNotFoundError, match="missing.json: no such file"):
        resolve_noise_model_path(str(tmp_path / "missing.json"))


def test_noise_process_delays_multi_step_observations_and_not_single_step_ones() -> None:
    """A pure 80 ms latency: two 40 ms steps late in multi-step mode; a single-step episode's two observations
    are a whole trajectory apart, so its P_DLO is not delayed at all."""
    from dyndlo_vision.tasks.noise import NoiseProcess

    model = ObservationNoiseModel(latency_s=0.08)
    truths = [np.array([0.1 * k, 0.0, 1.0]) for k in range(6)]
    multi = NoiseProcess(model, 0.04, multi_step=True)
    single = NoiseProcess(model, 0.04, multi_step=False)
    multi.reset(0)
    single.reset(0)
    for k, p in enumerate(truths):
        delayed, measured = multi.corrupt(p)
        np.testing.assert_allclose(delayed, truths[max(k - 2, 0)])
        now, _ = single.corrupt(p)
        np.testing.assert_allclose(now, p)
        assert measured


def test_a_path_to_a_shipped_model_in_any_install_is_its_name(tmp_path) -> None:
    from dyndlo_vision.tasks.noise import packaged_noise_model_path, portable_noise_model

    assert portable_noise_model(str(packaged_noise_model_path())) == "packaged"
    assert portable_noise_model("/tmp/tt17/dyndlo_vision/data/noise_model_tracking.json") == "packaged"
    assert portable_noise_model("packaged") == "packaged" and portable_noise_model(None) is None
    mine = str(tmp_path / "data" / "noise_model_tracking.json")  # the same name, not in a package
    assert portable_noise_model(mine) == mine
    vault = str(shipped_noise_model_path("vaulting-two-cameras"))
    assert portable_noise_model(vault) == "vaulting-two-cameras"
    assert portable_noise_model("/tmp/x/dyndlo_vision/data/noise_model_vaulting_two_cameras.json") == (
        "vaulting-two-cameras")


def test_each_shipped_name_opens_its_own_model_and_each_task_its_own_tracker() -> None:
    """``vaulting-two-cameras`` is the vault loop's two-camera fit (about 1 mm per axis, no speed term), not
    tip control's one-camera one (about 4 mm, plus a term per m/s), and it is vaulting's own model (what
    ``demo --observation noisy`` uses by default); a name that is not shipped is refused with the names that
    are."""
    from dyndlo_vision.tasks.noise import (
        SHIPPED_NOISE_MODELS,
        noise_model_file,
        resolve_noise_model_path,
        task_noise_model,
    )

    tip = ObservationNoiseModel.load(noise_model_file("packaged"))
    vault = ObservationNoiseModel.load(noise_model_file("vaulting-two-cameras"))
    assert "--task vaulting" in vault.source and "--task vaulting" not in tip.source
    assert max(vault.std_m) < 2e-3 < max(tip.std_m) and vault.std_per_speed_s == 0 < tip.std_per_speed_s
    assert task_noise_model("vaulting") == "vaulting-two-cameras"
    assert task_noise_model("tip-control") == task_noise_model("hooking") == "packaged"
    for name in SHIPPED_NOISE_MODELS:
        assert resolve_noise_model_path(name) == name and noise_model_file(name).is_file()
    with pytest.raises(ValueError, match="vaulting-two-cameras"):
        shipped_noise_model_path("vaulting-one-camera")
    with pytest.raises(FileNotFoundError, match="'packaged' or 'vaulting-two-cameras'"):
        resolve_noise_model_path("vaulting-one-camera")


def test_make_env_reads_a_shipped_name() -> None:
    from dyndlo_vision.tasks.registry import make_env

    env = make_env("vaulting", multi_step=True, obs_noise="vaulting-two-cameras")
    wrapper = env
    while not isinstance(wrapper, NoisyObservation):
        wrapper = wrapper.env
    assert wrapper.model == ObservationNoiseModel.load(shipped_noise_model_path("vaulting-two-cameras"))
    env.close()
