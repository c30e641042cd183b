"""The correction gate: a logistic classifier on the student's input at the late commitment that decides
whether the whole correction is made (dyndlo_vision.policies.correction_gate, learning.correction_gate)."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import dyndlo_vision  # noqa: F401  (registers the environment ids)
from dyndlo_vision import policies
from dyndlo_vision.learning.correction_gate import fit_gate, fit_logistic, gate_examples, line_direction
from dyndlo_vision.learning.distill import Episodes, ReplanSearch, with_history, with_noise
from dyndlo_vision.policies.correction_gate import CorrectionGate


def gate(size: int = 4, actions: int = 3, **changes) -> CorrectionGate:
    direction = (0.6, 0.0, -0.8) if actions == 3 else (1.0,) + (0.0,) * (actions - 1)
    values = dict(decision=2, direction=direction,
                  length=0.3, mean=(0.0,) * size, scale=(1.0,) * size, weights=(1.0,) + (0.0,) * (size - 1),
                  bias=0.0, threshold=0.5)
    values.update(changes)
    return CorrectionGate(**values)


# --------------------------------------------------------------------------------------- the logistic fit
def test_the_fit_recovers_a_known_logistic_model() -> None:
    """Draws from a known logistic model: the fitted weights (in the raw inputs' units) come back within a
    few standard errors, and the penalised likelihood's gradient is zero at the answer."""
    rng = np.random.default_rng(1)
    n = 100_000  # standard errors of the weights 0.01-0.03
    x = rng.normal([0.3, -0.2, 0.0], [2.0, 0.5, 1.0], size=(n, 3))
    true_w, true_b = np.array([0.8, -1.5, 0.0]), -0.7
    y = rng.random(n) < 1 / (1 + np.exp(-(x @ true_w + true_b)))
    mean, scale, w, b = fit_logistic(x, y, l2=1e-6)
    raw_w = w / scale
    raw_b = b - float(np.dot(raw_w, mean))
    assert np.allclose(raw_w, true_w, atol=0.06)
    assert abs(raw_b - true_b) < 0.06
    z = (x - mean) / scale
    p = 1 / (1 + np.exp(-(z @ w + b)))
    assert np.max(np.abs(z.T @ (p - y) + 1e-6 * w)) < 1e-6 and abs(np.sum(p - y)) < 1e-6


def test_a_stronger_penalty_shrinks_the_weights_not_the_bias() -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=(400, 2))
    y = x[:, 0] + 0.5 * rng.normal(size=400) > 0.8
    weak = fit_logistic(x, y, l2=0.01)
    strong = fit_logistic(x, y, l2=1000.0)
    assert np.linalg.norm(strong[2]) < 0.1 * np.linalg.norm(weak[2])
    # with the weights near 0 the bias alone fits the base rate
    assert abs(1 / (1 + np.exp(-strong[3])) - y.mean()) < 0.02


@pytest.mark.parametrize("x, y, l2, match", [
    (np.zeros((5, 2)), np.zeros(5, bool), 1.0, "both classes"),
    (np.zeros((5, 2)), np.ones(5, bool), 1.0, "both classes"),
    (np.zeros(5), np.array([0, 1, 0, 1, 0], bool), 1.0, r"\(n, d\)"),
    (np.zeros((5, 2)), np.array([0, 1, 0, 1], bool), 1.0, r"\(n,\)"),
    (np.zeros((5, 2)), np.array([0, 1, 0, 1, 0], bool), 0.0, "l2 must be positive"),
])
def test_the_fit_refuses_what_it_cannot_fit(x, y, l2, match) -> None:
    with pytest.raises(ValueError, match=match):
        fit_logistic(x, y, l2)


# ------------------------------------------------------------------------------------------------ the gate
def test_the_gate_corrects_whole_from_its_threshold_and_not_below() -> None:
    g = gate(mean=(1.0, 0, 0, 0), scale=(2.0, 1, 1, 1), bias=-0.5, threshold=0.5)
    # z = (x0 - 1) / 2 - 0.5: zero (p = 0.5, the threshold itself) at x0 = 2
    at = np.array([2.0, 9, 9, 9])
    assert g.probability(at) == pytest.approx(0.5)
    assert np.allclose(g.correction(at), 0.3 * np.array([0.6, 0.0, -0.8]))
    assert np.allclose(g.correction(np.array([1.99, 0, 0, 0])), 0.0)
    assert g.probability(np.array([5.0, 0, 0, 0])) == pytest.approx(1 / (1 + np.exp(-1.5)))
    assert g.probability(np.array([-1e6, 0, 0, 0])) == 0.0  # no overflow far out


@pytest.mark.parametrize("changes, match", [
    ({"direction": (1.0, 1.0, 0.0)}, "unit vector"),
    ({"scale": (1.0, 0.0, 1.0, 1.0)}, "scale must be positive"),
    ({"weights": (1.0, 0.0)}, "one size"),
    ({"threshold": 1.0}, "probability"),
    ({"threshold": 0.0}, "probability"),
    ({"decision": -1}, "decision index"),
    ({"length": float("nan")}, "finite"),
])
def test_bad_gates_are_refused_by_name(changes, match) -> None:
    with pytest.raises(ValueError, match=match):
        gate(**changes)


def test_the_gate_refuses_an_input_of_another_size() -> None:
    with pytest.raises(ValueError, match="4 values"):
        gate().probability(np.zeros(5))


def test_the_gate_survives_json() -> None:
    g = gate(bias=0.25, threshold=0.3, mean=(0.1, 0.2, 0.3, 0.4))
    again = CorrectionGate.from_json(json.loads(json.dumps(g.to_json())))
    assert again == g
    values = g.to_json()
    del values["bias"]
    with pytest.raises(ValueError, match="keys"):
        CorrectionGate.from_json(values)


# --------------------------------------------------------------------------------------- the gated policy
def save_student(tmp_path, correction_gate: dict | None, history: int = 2) -> tuple:
    """A small student reading a P_DLO history of 2, saved with ``correction_gate`` in its metadata."""
    from dyndlo_vision.learning.distill import new_student
    from dyndlo_vision.tasks.wrappers import StudentFeaturesWrapper

    env = StudentFeaturesWrapper(gym.make("DynDLO/TipControl-v0", multi_step=True), p_dlo_history=2)
    network = new_student(env, (8,), seed=3)
    network.save(tmp_path / "model.zip")
    meta = {"algo": "ppo", "multi_step": True, "p_dlo_history": history}
    if correction_gate is not None:
        meta["correction_gate"] = correction_gate
    (tmp_path / "model.json").write_text(json.dumps(meta))
    return network, env


def test_the_loaded_policy_corrects_at_its_decision_only(tmp_path) -> None:
    """Always due (bias 50): the gated policy's action is the network's plus the correction at decision 2 of
    every episode, and the network's alone at every other decision; reset restarts the count."""
    size, actions = 12 + 6, 9
    direction = np.zeros(actions)
    direction[4] = 1.0
    always = gate(size, actions, direction=tuple(direction), length=0.25, bias=50.0)
    network, env = save_student(tmp_path, always.to_json())
    model = policies.load(tmp_path / "model.zip", env=gym.make("DynDLO/TipControl-v0", multi_step=True))
    assert isinstance(model, policies.GatedPolicy) and model.observation_space.shape == (12,)
    seen = [env.reset(seed=5)[0]]
    for _ in range(4):
        seen.append(env.step(np.zeros(actions, dtype=np.float32))[0])
    offline = np.array([network.predict(o, deterministic=True)[0] for o in seen])
    for _episode in range(2):
        model.reset()
        assert model.last_gate_probability is None
        online = np.array([model.predict(o[:12])[0] for o in seen])
        expected = offline.copy()
        expected[2] = np.clip(expected[2] + 0.25 * direction, -1, 1)
        assert np.allclose(online, expected, atol=1e-6)
        assert model.last_gate_probability == pytest.approx(1.0)
    env.close()


def test_a_gate_that_is_not_due_leaves_the_student_alone(tmp_path) -> None:
    never = gate(18, 9, direction=(1.0,) + (0.0,) * 8, bias=-50.0)
    network, env = save_student(tmp_path, never.to_json())
    model = policies.load(tmp_path / "model.zip")
    obs = [env.reset(seed=2)[0]]
    for _ in range(3):
        obs.append(env.step(np.zeros(9, dtype=np.float32))[0])
    model.reset()
    online = np.array([model.predict(o[:12])[0] for o in obs])
    assert np.allclose(online, [network.predict(o, deterministic=True)[0] for o in obs], atol=1e-6)
    assert model.last_gate_probability == pytest.approx(0.0, abs=1e-12)
    env.close()


@pytest.mark.parametrize("size, actions, history, match", [
    (17, 9, 2, "inputs of 17"),
    (18, 8, 2, "actions of 8"),
    (18, 9, 0, "needs a student with p_dlo_history"),
])
def test_a_gate_that_does_not_fit_its_student_is_refused_on_load(tmp_path, size, actions, history,
                                                                  match) -> None:
    bad = gate(size, actions, direction=(1.0,) + (0.0,) * (actions - 1))
    save_student(tmp_path, bad.to_json(), history=history)
    with pytest.raises(ValueError, match=match):
        policies.load(tmp_path / "model.zip")


def test_a_broken_gate_in_the_metadata_is_refused_on_load(tmp_path) -> None:
    values = gate(18, 9, direction=(1.0,) + (0.0,) * 8).to_json()
    values["threshold"] = 2.0
    save_student(tmp_path, values)
    with pytest.raises(ValueError, match="bad correction_gate.*threshold"):
        policies.load(tmp_path / "model.zip")


# ------------------------------------------------------------------------------------ fitting it to a run
def fake_run(tmp_path, commit: int = 2, candidates: str = "line:31"):
    """A run folder of two rounds, 12-dimensional observations: 5 episodes each of 4 decisions (one of 2),
    corrected where the decision-``commit`` observation's P_DLO x is positive."""
    rng = np.random.default_rng(7)
    for r in range(2):
        parts = []
        for i in range(5):
            n = 2 if i == 4 else 4
            seed = 1000 * (r + 1) + i
            obs = rng.normal(size=(n, 12)).astype(np.float32)
            corrected = bool(n > commit and obs[commit, 6] > 0)
            parts.append(Episodes(obs, obs.copy(), rng.normal(size=(n, 9)).astype(np.float32),
                                  np.full(n, seed), np.array([True]), np.array([False]), np.array([0.0]),
                                  np.array([int(corrected)])))
        Episodes.concatenate(parts).save(tmp_path / f"round{r}.npz")
    config = {"noise_model": None, "p_dlo_history": 2, "decision_clock": False,
              "teacher_commit_decision": commit, "search_candidates": candidates}
    (tmp_path / "config.json").write_text(json.dumps(config))
    return tmp_path


def test_the_examples_are_the_students_inputs_at_the_commitment(tmp_path) -> None:
    run = fake_run(tmp_path)
    ex = gate_examples(run)
    assert ex["decision"] == 2 and ex["inputs"].shape == (8, 18)  # the 2-decision episodes have no decision 2
    for r in range(2):
        data = Episodes.load(run / f"round{r}.npz")
        seen = with_history(with_noise(data, None), 2)
        for seed, replans in zip(data.episode_seeds[:4], data.replans[:4], strict=True):
            row = np.flatnonzero(data.seeds == seed)[2]
            at = int(np.flatnonzero(ex["seeds"] == seed)[0])
            assert np.allclose(ex["inputs"][at], seen.observations[row])
            assert ex["corrected"][at] == (replans > 0) == (data.observations[row, 6] > 0)


def test_a_fitted_gate_separates_what_its_run_separates(tmp_path) -> None:
    run = fake_run(tmp_path)
    g = fit_gate(run, length=0.2, l2=0.1)
    ex = gate_examples(run)
    p = np.array([g.probability(x) for x in ex["inputs"]])
    assert ex["corrected"].any() and (~ex["corrected"]).any()
    assert p[ex["corrected"]].min() > 0.5 > p[~ex["corrected"]].max()
    assert np.allclose(g.direction, line_direction("line:31", 9)) and g.length == 0.2 and g.decision == 2


def test_the_gates_direction_is_the_lines() -> None:
    search = ReplanSearch(candidates="line:5")
    expected = search.offsets(9)[0] / np.linalg.norm(search.offsets(9)[0])
    assert np.allclose(line_direction("line:5", 9), expected)
    shared = ReplanSearch(candidates="shared").offsets(9)[5]
    assert np.allclose(line_direction("line:5", 9), shared / np.linalg.norm(shared))
    with pytest.raises(ValueError, match="not a line"):
        line_direction("shared", 9)


def test_a_folder_that_is_not_a_run_is_refused(tmp_path) -> None:
    with pytest.raises(FileNotFoundError, match="config.json"):
        gate_examples(tmp_path)
    (tmp_path / "config.json").write_text(json.dumps({"teacher_commit_decision": 3}))
    with pytest.raises(FileNotFoundError, match="round"):
        gate_examples(tmp_path)
    (tmp_path / "config.json").write_text(json.dumps({"teacher_commit_decision": None}))
    with pytest.raises(ValueError, match="no teacher_commit_decision"):
        gate_examples(tmp_path)


def test_torch_is_not_needed_to_use_a_gate() -> None:
    """The gate is numpy: its module imports neither torch nor stable-baselines3."""
    import ast
    from pathlib import Path

    source = Path(policies.__file__).with_name("correction_gate.py").read_text()
    names = {a.name.split(".")[0] for node in ast.walk(ast.parse(source)) if isinstance(node, ast.Import)
             for a in node.names}
    names |= {node.module.split(".")[0] for node in ast.walk(ast.parse(source))
              if isinstance(node, ast.ImportFrom) and node.module}
    assert not names & {"torch", "stable_baselines3"}


# ------------------------------------------------------------------------------------- dyndlo-vision gate
def gate_run(tmp_path):
    """A fake line run (see :func:`fake_run`) with a student (history 2) and its metadata."""
    (tmp_path / "run").mkdir()
    run = fake_run(tmp_path / "run")
    save_student(run, None)
    return run


def test_the_gate_command_writes_a_gated_policy_that_loads(tmp_path, capsys) -> None:
    from dyndlo_vision.cli import main

    run = gate_run(tmp_path)
    out = tmp_path / "out" / "gated.zip"
    assert main(["gate", str(run), "--length", "0.25", "--l2", "0.1", "--out", str(out)]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["examples"] == 8 and report["corrected"] == int(gate_examples(run)["corrected"].sum())
    assert "auc" in report["held_out"]
    model = policies.load(out)
    assert isinstance(model, policies.GatedPolicy)
    assert model.gate.length == 0.25 and model.gate.decision == 2
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["p_dlo_history"] == 2 and meta["correction_gate_fit"]["run"] == str(run)
    assert out.read_bytes() == (run / "model.zip").read_bytes()


@pytest.mark.parametrize("extra, match", [
    (["--length", "0"], "non-zero length"),
    (["--length", "nan"], "finite"),
    (["--length", "0.2", "--threshold", "1.5"], "probability"),
    (["--length", "0.2", "--l2", "-1"], "positive number"),
    (["--length", "0.2", "--model", "nowhere.zip"], "does not exist"),
])
def test_the_gate_command_refuses_bad_options_and_writes_nothing(tmp_path, capsys, extra, match) -> None:
    from dyndlo_vision.cli import main

    run = gate_run(tmp_path)
    out = tmp_path / "out" / "gated.zip"
    with pytest.raises(SystemExit) as exit_info:
        main(["gate", str(run), *extra, "--out", str(out)])
    assert exit_info.value.code == 2
    assert re_search(match, capsys.readouterr().err)
    assert not (tmp_path / "out").exists()


def test_the_gate_command_refuses_a_student_the_gate_does_not_fit(tmp_path, capsys) -> None:
    """--model: a student that reads another history than the run's features cannot take the gate."""
    from dyndlo_vision.learning.distill import new_student
    from dyndlo_vision.tasks.wrappers import StudentFeaturesWrapper

    run = gate_run(tmp_path)
    other = tmp_path / "other"
    other.mkdir()
    env = StudentFeaturesWrapper(gym.make("DynDLO/TipControl-v0", multi_step=True), p_dlo_history=3)
    new_student(env, (8,), seed=1).save(other / "student.zip")
    (other / "student.json").write_text(json.dumps({"algo": "ppo", "multi_step": True, "p_dlo_history": 3}))
    out = tmp_path / "out" / "gated.zip"
    with pytest.raises(SystemExit) as exit_info:
        main_cli(["gate", str(run), "--length", "0.2", "--model", str(other / "student.zip"),
                  "--out", str(out)])
    assert exit_info.value.code == 2
    assert "inputs of 18" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def main_cli(argv: list[str]) -> int:
    from dyndlo_vision.cli import main

    return main(argv)


def re_search(pattern: str, text: str) -> bool:
    import re

    return re.search(pattern, text) is not None


def test_the_gate_command_refuses_a_run_that_is_not_a_line_or_an_existing_output(tmp_path, capsys) -> None:
    from dyndlo_vision.cli import main

    run = gate_run(tmp_path)
    config = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**config, "search_candidates": "shared"}))
    out = tmp_path / "gated.zip"
    with pytest.raises(SystemExit):
        main(["gate", str(run), "--length", "0.2", "--out", str(out)])
    assert "not a line" in capsys.readouterr().err and not out.exists()
    (run / "config.json").write_text(json.dumps(config))
    out.write_bytes(b"mine")
    with pytest.raises(SystemExit):
        main(["gate", str(run), "--length", "0.2", "--out", str(out)])
    assert "--overwrite" in capsys.readouterr().err and out.read_bytes() == b"mine"
    assert not out.with_suffix(".json").exists()
    assert main(["gate", str(run), "--length", "0.2", "--out", str(out), "--overwrite"]) == 0
    assert isinstance(policies.load(out), policies.GatedPolicy)


def test_the_demo_records_whether_the_gate_corrected(tmp_path) -> None:
    """``demo`` runs a gated policy, and each episode's record says how sure its gate was and whether it
    corrected."""
    from dyndlo_vision.cli import main

    always = gate(18, 9, direction=(1.0,) + (0.0,) * 8, decision=1, length=0.05, bias=50.0)
    save_student(tmp_path, always.to_json())
    meta = json.loads((tmp_path / "model.json").read_text())
    (tmp_path / "model.json").write_text(json.dumps({**meta, "task": "tip-control"}))
    out = tmp_path / "demo"
    policy = str(tmp_path / "model.zip")
    assert main(["demo", "--policy", policy, "--observation", "true", "--quiet", "--out", str(out)]) == 0
    episode = json.loads((out / "metrics.json").read_text())["episodes"][0]
    assert episode["gate_corrected"] is True and episode["gate_probability"] == pytest.approx(1.0)
