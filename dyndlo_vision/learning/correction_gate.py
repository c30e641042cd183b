"""Fit a :class:`~dyndlo_vision.policies.correction_gate.CorrectionGate` to a ``distill --search-candidates
line:N`` run: whether the late-committing expert corrected each episode, from the student's input at the
commitment decision, as the student saw it (the run's noise model and features).

The classifier is an L2-regularised logistic regression on standardised inputs, fitted by Newton's method:
deterministic, and small enough to live in the policy's metadata. The correction it gates is
``length * direction``, with ``direction`` the line's unit vector; ``length`` is the caller's (a ray: one
length for every cable, so that the student's label does not flip between look-alike cables).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dyndlo_vision.policies.correction_gate import CorrectionGate


def fit_logistic(inputs: NDArray[np.floating[Any]], labels: NDArray[np.bool_], l2: float = 1.0,
                 iterations: int = 50) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                                                float]:
    """L2-regularised logistic regression of ``labels`` on standardised ``inputs`` (Newton's method).

    The penalty ``l2 / 2 * |w|^2`` is on the weights, not the bias. Inputs are standardised by their mean and
    standard deviation (a constant column gets scale 1).

    Returns:
        ``(mean, scale, weights, bias)``.

    Raises:
        ValueError: Shapes disagree, fewer than one example of each class, or ``l2`` is not positive.
    """
    x = np.asarray(inputs, dtype=np.float64)
    y = np.asarray(labels, dtype=bool)
    if x.ndim != 2 or y.shape != (x.shape[0],):
        raise ValueError(f"inputs (n, d) and labels (n,) expected, got {x.shape} and {y.shape}")
    if not (y.any() and (~y).any()):
        raise ValueError(f"labels need both classes; got {int(y.sum())} of {y.size} true")
    if not l2 > 0:
        raise ValueError(f"l2 must be positive, got {l2!r}")
    mean = x.mean(axis=0)
    scale = x.std(axis=0)
    scale[scale < 1e-12] = 1.0
    z = np.hstack([(x - mean) / scale, np.ones((len(x), 1))])
    theta = np.zeros(z.shape[1])
    theta[-1] = np.log(y.mean() / (1 - y.mean()))
    penalty = np.full(z.shape[1], float(l2))
    penalty[-1] = 0.0
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-np.clip(z @ theta, -50, 50)))
        gradient = z.T @ (p - y) + penalty * theta
        hessian = (z * (p * (1 - p))[:, None]).T @ z + np.diag(penalty) + 1e-9 * np.eye(z.shape[1])
        step = np.linalg.solve(hessian, gradient)
        theta -= step
        if np.max(np.abs(step)) < 1e-10:
            break
    return mean, scale, theta[:-1], float(theta[-1])


def gate_examples(run: Path, decision: int | None = None) -> dict[str, Any]:
    """The student's inputs at the run's commitment decision, and whether the expert corrected there.

    Every round file of the run (``round<r>.npz``) is read; each episode long enough gives one row: its
    observation at decision K re-drawn through the run's noise model, with the run's features
    (:func:`~dyndlo_vision.learning.distill.with_noise`, ``with_history``: exactly what its student was fitted
    on), and the episode's ``replans`` count > 0.

    Returns:
        ``inputs`` (n, d), ``corrected`` (n,), ``seeds`` (n,), ``rounds`` (n,), ``decision`` K, the
        run's ``config`` and its ``action_size``.

    Raises:
        FileNotFoundError: No ``config.json`` or round files in ``run``.
        ValueError: The run has no commitment decision and none is given.
    """
    from dyndlo_vision.learning.distill import Episodes, with_history, with_noise
    from dyndlo_vision.tasks.noise import noise_model_file

    run = Path(run)
    config_file = run / "config.json"
    if not config_file.is_file():
        raise FileNotFoundError(f"{run} is not a distill run folder (no config.json)")
    config = json.loads(config_file.read_text())
    k = decision if decision is not None else config.get("teacher_commit_decision")
    if k is None:
        raise ValueError(f"run {run} has no teacher_commit_decision; give the decision")
    files = sorted(run.glob("round*.npz"), key=lambda p: int(p.stem[5:]))
    if not files:
        raise FileNotFoundError(f"{run} has no round<r>.npz files")
    noise = noise_model_file(config["noise_model"]) if config.get("noise_model") else None
    inputs, corrected, seeds, rounds = [], [], [], []
    action_size = 0
    for file in files:
        data = Episodes.load(file)
        action_size = int(data.actions.shape[1])
        seen = with_history(with_noise(data, noise), int(config.get("p_dlo_history") or 0),
                            bool(config.get("decision_clock")))
        for seed, replans in zip(data.episode_seeds, data.replans, strict=True):
            rows = np.flatnonzero(data.seeds == seed)
            if len(rows) > k:
                inputs.append(seen.observations[rows[k]])
                corrected.append(replans > 0)
                seeds.append(int(seed))
                rounds.append(int(file.stem[5:]))
    return {"inputs": np.array(inputs, dtype=np.float64), "corrected": np.array(corrected, dtype=bool),
            "seeds": np.array(seeds), "rounds": np.array(rounds), "decision": int(k), "config": config,
            "action_size": action_size}


def line_direction(candidates: str, action_size: int) -> NDArray[np.float64]:
    """The unit direction of a ``"line:N"`` search's corrections (:class:`~dyndlo_vision.learning.distill.
    ReplanSearch`; ValueError for candidates that are not a line)."""
    from dyndlo_vision.learning.distill import ReplanSearch

    return ReplanSearch(candidates=candidates).line_direction(action_size)


def fit_gate(run: Path, length: float, threshold: float = 0.5, l2: float = 1.0,
             examples: dict[str, Any] | None = None) -> CorrectionGate:
    """The gate of a line run: its classifier fitted on every round, correcting by ``length`` along the
    run's line (see :func:`gate_examples`, :func:`fit_logistic`; ``examples``: the run's, if already read)."""
    examples = examples if examples is not None else gate_examples(run)
    config = examples["config"]
    mean, scale, weights, bias = fit_logistic(examples["inputs"], examples["corrected"], l2)
    direction = line_direction(config.get("search_candidates", "episode"), examples["action_size"])
    return CorrectionGate(decision=examples["decision"], direction=tuple(direction), length=float(length),
                          mean=tuple(mean), scale=tuple(scale), weights=tuple(weights), bias=bias,
                          threshold=float(threshold))


def held_out_probabilities(examples: dict[str, Any], l2: float = 1.0) -> NDArray[np.float64]:
    """Each example's gate probability from a classifier fitted on the *other* rounds of its run (leave one
    round out): how the gate does on cables it was not fitted on.

    Raises:
        ValueError: Fewer than two rounds, or a round without which one class is missing.
    """
    x, y, rounds = examples["inputs"], examples["corrected"], examples["rounds"]
    if len(np.unique(rounds)) < 2:
        raise ValueError("a held-out check needs a run of at least two rounds")
    p = np.zeros(len(y))
    for r in np.unique(rounds):
        held = rounds == r
        mean, scale, weights, bias = fit_logistic(x[~held], y[~held], l2)
        p[held] = 1.0 / (1.0 + np.exp(-np.clip(((x[held] - mean) / scale) @ weights + bias, -50, 50)))
    return p


def rank_auc(scores: NDArray[np.floating[Any]], labels: NDArray[np.bool_]) -> float:
    """The area under the ROC curve: the chance that a random positive scores above a random negative
    (ties count half)."""
    s, y = np.asarray(scores, dtype=np.float64), np.asarray(labels, dtype=bool)
    pos, neg = s[y], s[~y]
    if not (pos.size and neg.size):
        raise ValueError("an AUC needs both classes")
    return float((pos[:, None] > neg[None]).mean() + 0.5 * (pos[:, None] == neg[None]).mean())
