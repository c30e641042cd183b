"""label_conflict: labels that are a function of what the student sees agree between look-alike decisions;
labels that also depend on a hidden phase do not, until the phase is appended."""

from __future__ import annotations

import numpy as np
import pytest

from dyndlo_vision.learning.diagnostics import label_conflict, shuffled_control, standardise


def episodes(n_episodes: int = 40, steps: int = 25, seed: int = 0) -> tuple[np.ndarray, ...]:
    """Observations that trace the same loop in every episode, at a random speed and starting phase, so
    that one point of the loop is visited at different times; ``t`` is the decision's time."""
    rng = np.random.default_rng(seed)
    obs, t, ids = [], [], []
    for e in range(n_episodes):
        speed, phase = rng.uniform(0.5, 1.5), rng.uniform(0, 2 * np.pi)
        k = np.arange(steps)
        angle = phase + speed * 0.25 * k
        obs.append(np.c_[np.cos(angle), np.sin(angle)] + rng.normal(0, 0.01, (steps, 2)))
        t.append(0.04 * k)
        ids.append(np.full(steps, e))
    return np.concatenate(obs), np.concatenate(t), np.concatenate(ids)


def test_labels_that_the_observation_determines_do_not_conflict() -> None:
    obs, t, ids = episodes()
    labels = np.c_[np.tanh(obs[:, 0] + obs[:, 1]), obs[:, 0] * obs[:, 1]]
    hidden = np.c_[np.sin(25 * t), np.cos(25 * t)]  # the same label range, but set by the time alone
    own = label_conflict(obs, labels, ids)
    timed = label_conflict(obs, hidden, ids)
    assert own.pairs == len(obs)
    assert own.conflict < 0.01 and own.close_conflict <= own.conflict * 1.5
    assert timed.conflict > 20 * own.conflict  # same observations, labels that depend on what is not seen


def test_the_feature_the_labels_depend_on_removes_the_conflict_and_a_shuffled_one_does_not() -> None:
    obs, t, ids = episodes()
    labels = np.c_[np.sin(25 * t) + 0.1 * obs[:, 0], np.cos(25 * t)]
    without = label_conflict(obs, labels, ids).conflict
    with_clock = label_conflict(np.c_[obs, t], labels, ids).conflict
    shuffled = label_conflict(np.c_[obs, shuffled_control(t)], labels, ids).conflict
    assert with_clock < 0.2 * without
    assert shuffled > 0.6 * without


def test_a_neighbour_is_always_from_another_episode() -> None:
    """Within an episode consecutive decisions look alike and share a label: pairing them would hide the
    conflict between episodes (each episode here has its own constant label)."""
    ids = np.repeat(np.arange(10), 50)
    along = np.tile(0.002 * np.arange(50), 10)  # each episode's own decisions 0.002 apart ...
    obs = np.c_[along, 0.05 * ids]  # ... and episodes 0.05 apart
    labels = np.c_[ids, -ids] / 10.0
    result = label_conflict(obs, labels, ids)
    assert result.pairs == 500
    assert np.isclose(result.conflict, 0.01)  # always the next episode's label, 0.1 away


def test_constant_columns_are_dropped_and_bad_input_refused() -> None:
    x = np.c_[np.arange(5.0), np.full(5, 3.0)]
    z = standardise(x)
    assert z.shape == (5, 1) and np.isclose(z.std(), 1.0) and np.isclose(z.mean(), 0.0)
    with pytest.raises(ValueError, match="two episodes"):
        label_conflict(np.ones((4, 2)), np.ones((4, 1)), np.zeros(4))
    with pytest.raises(ValueError, match="episode ids"):
        label_conflict(np.ones((4, 2)), np.ones((3, 1)), np.arange(4))
