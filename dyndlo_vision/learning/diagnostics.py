"""Diagnostics of imitation data: do an expert's labels conflict where the student's observations agree?

A student regresses the expert's label on what it observes. If two decisions look alike to it and the expert
labelled them differently (because its label depends on something the student does not see: the time in the
expert's plan, the cable's parameters, where a search stopped), no student can fit both, and it learns their
average. :func:`label_conflict` measures that directly: it pairs every decision with its nearest neighbour
from *another* episode in the student's observation space, and reports how far apart their labels are. Run it
with and without a candidate feature appended (e.g. the decision clock): a feature the labels depend on makes
the neighbours' labels agree; one they do not depend on changes little (:func:`shuffled_control` gives that
baseline, the same values assigned to the wrong decisions).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["LabelConflict", "label_conflict", "shuffled_control"]


@dataclass(frozen=True)
class LabelConflict:
    """What :func:`label_conflict` found.

    Attributes:
        pairs: Decisions that had a neighbour from another episode.
        neighbour_distance: Median distance to that neighbour, in standardised units.
        conflict: Mean over pairs of the mean squared label difference per action dimension (the units of a
            student's fit MSE: twice the irreducible MSE where each pair is one state labelled twice).
        close_conflict: The same over the closest half of the pairs.
    """

    pairs: int
    neighbour_distance: float
    conflict: float
    close_conflict: float


def standardise(features: NDArray[np.floating]) -> NDArray[np.float64]:
    """Columns scaled to unit standard deviation around their mean; constant columns dropped."""
    x = np.asarray(features, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"expected (N, n) features, got shape {x.shape}")
    std = x.std(axis=0)
    keep = std > 1e-9
    return (x[:, keep] - x[:, keep].mean(axis=0)) / std[keep]


def label_conflict(
    observations: NDArray[np.floating],
    labels: NDArray[np.floating],
    episode_ids: NDArray[np.integer],
    neighbours: int = 16,
) -> LabelConflict:
    """How far apart the labels of look-alike decisions from different episodes are.

    Args:
        observations: (N, n) what the student reads at each decision (standardised here, per column).
        labels: (N, m) the expert's actions.
        episode_ids: (N,) which episode each decision belongs to; a neighbour must come from another one.
        neighbours: How many nearest candidates are searched for one from another episode.

    Raises:
        ValueError: Mismatched shapes, or fewer than two episodes.
    """
    from scipy.spatial import cKDTree

    obs = np.asarray(observations)
    act = np.asarray(labels, dtype=np.float64)
    ids = np.asarray(episode_ids)
    if obs.ndim != 2 or act.ndim != 2 or not len(obs) == len(act) == len(ids):
        raise ValueError(
            f"expected (N, n) observations, (N, m) labels and N episode ids, got {obs.shape}, {act.shape}, "
            f"{ids.shape}"
        )
    if len(np.unique(ids)) < 2:
        raise ValueError("label conflict needs decisions from at least two episodes")
    z = standardise(obs)
    k = min(int(neighbours) + 1, len(z))
    distance, index = cKDTree(z).query(z, k=k)
    other = ids[index] != ids[:, None]
    has = other.any(axis=1)
    first = np.argmax(other, axis=1)
    rows = np.flatnonzero(has)
    partner = index[rows, first[rows]]
    d = distance[rows, first[rows]]
    diff = np.mean((act[rows] - act[partner]) ** 2, axis=1)
    close = d <= np.median(d)
    return LabelConflict(
        pairs=int(len(rows)),
        neighbour_distance=float(np.median(d)),
        conflict=float(diff.mean()),
        close_conflict=float(diff[close].mean()),
    )


def shuffled_control(feature: NDArray[np.floating], seed: int = 0) -> NDArray[np.floating]:
    """``feature``'s rows in a random order: the same values, unrelated to the decisions they are put on."""
    return np.random.default_rng(seed).permutation(np.asarray(feature))
