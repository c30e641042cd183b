"""Fitting a noise model to what a tracker gave: per-frame records of the true P_DLO, the estimate read and
the true velocity (how ``benchmarks/tracking_accuracy.py --fit-out`` and ``benchmarks/loop_noise_model.py``
make the shipped models)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import nnls

from dyndlo_vision.tasks.noise.model import MAX_LATENCY_S, ObservationNoiseModel

__all__ = ["DEFAULT_TCP_POSITION_STD_M", "DEFAULT_TCP_VELOCITY_STD_M_S", "dropout_runs", "fit_noise_model"]

#: TCP noise given to a fitted model unless told otherwise (our choice, not a measurement): 0.2 mm and 5 mm/s
#: per axis, far above the simulator's micrometre fingerprint of the cable and far below the task's scale.
DEFAULT_TCP_POSITION_STD_M = 2e-4
DEFAULT_TCP_VELOCITY_STD_M_S = 5e-3

# E|r| = sigma * sqrt(2 / pi) for a zero-mean normal r: scales mean absolute residuals to standard deviations.
_ABS_TO_STD = math.sqrt(math.pi / 2.0)


def fit_noise_model(
    truth: ArrayLike,
    estimate: ArrayLike,
    velocity: ArrayLike,
    episode: ArrayLike | None = None,
    speed: ArrayLike | None = None,
    speed_dependent: bool = True,
    max_coast_steps: int = 7,
    source: str = "",
    tcp_position_std_m: float = DEFAULT_TCP_POSITION_STD_M,
    tcp_velocity_std_m_s: float = DEFAULT_TCP_VELOCITY_STD_M_S,
) -> ObservationNoiseModel:
    """Fits the model to per-observation records of the estimate the controller read.

    Bias and latency come from one least-squares fit of ``estimate - truth = bias - latency * velocity``
    over all axes (a first-order expansion of ``truth(t - latency)``); a negative latency (the estimate
    leads) is clipped to 0 and the bias refitted. The standard deviations come from the residuals: with
    ``speed_dependent``, a non-negative least-squares fit of ``sqrt(pi/2) |residual|`` (whose mean is
    the standard deviation for normal errors) against ``[one-hot axis, speed]``; otherwise the per-axis
    root mean square. Dropouts are the records whose estimate is NaN.

    Args:
        truth: (K, 3) true P_DLO at each read time (m).
        estimate: (K, 3) the estimate read then; a row with any NaN is a dropout.
        velocity: (K, 3) true P_DLO velocity at the read time (m/s), for the latency.
        episode: (K,) episode id per record (records of an episode contiguous, in time order); dropout
            runs never span episodes. None: one episode.
        speed: (K,) speed the standard deviation scales with, in the definition the user of the model
            applies (the wrapper uses the mean speed over the last control step). Default ``|velocity|``.
        speed_dependent: Fit ``std_per_speed_s`` (else 0).
        max_coast_steps: Stored as is (see the attribute).
        source: Stored as is.
        tcp_position_std_m: Stored as is: the TCP noise is not in the tracker's records (default
            :data:`DEFAULT_TCP_POSITION_STD_M`).
        tcp_velocity_std_m_s: Stored as is (default :data:`DEFAULT_TCP_VELOCITY_STD_M_S`).

    Raises:
        ValueError: On shape mismatches, non-finite truth/velocity/speed, or fewer than 10 observed
            records.
    """
    tru = _records(truth, "truth")
    est = np.asarray(estimate, dtype=np.float64)
    vel = _records(velocity, "velocity")
    k = tru.shape[0]
    if est.shape != (k, 3) or vel.shape != (k, 3):
        raise ValueError(
            f"truth, estimate and velocity must all be (K, 3) with the same K, got {tru.shape}, "
            f"{est.shape}, "
            f"{vel.shape}"
        )
    spd = (
        np.linalg.norm(vel, axis=1) if speed is None else np.asarray(speed, dtype=np.float64).reshape(-1)
    )
    if spd.shape != (k,) or not np.all(np.isfinite(spd)) or np.any(spd < 0):
        raise ValueError(f"speed must be (K,) = ({k},) finite values >= 0, got shape {spd.shape}")
    dropped = ~np.all(np.isfinite(est), axis=1)
    observed = ~dropped
    n_obs = int(np.count_nonzero(observed))
    if n_obs < 10:
        raise ValueError(f"need at least 10 records with an estimate to fit a noise model, got {n_obs}")
    runs = dropout_runs(dropped, episode)
    err = est[observed] - tru[observed]
    v = vel[observed]
    bias, latency = _fit_bias_latency(err, v)
    residual = err - bias + latency * v
    s = spd[observed]
    if speed_dependent:
        std0, gain = _fit_speed_std(residual, s)
    else:
        std0, gain = np.sqrt(np.mean(residual**2, axis=0)), 0.0
    return ObservationNoiseModel(
        bias_m=tuple(bias.tolist()),  # type: ignore[arg-type]
        std_m=tuple(std0.tolist()),  # type: ignore[arg-type]
        std_per_speed_s=float(gain),
        latency_s=min(float(latency), MAX_LATENCY_S),
        dropout_prob=float(np.mean(dropped)),
        dropout_mean_run=float(np.mean(runs)) if runs else 1.0,
        max_coast_steps=max_coast_steps,
        n_samples=k,
        source=source,
        tcp_position_std_m=tcp_position_std_m,
        tcp_velocity_std_m_s=tcp_velocity_std_m_s,
    )


def dropout_runs(dropped: ArrayLike, episode: ArrayLike | None = None) -> list[int]:
    """Lengths of the runs of consecutive True values, runs never spanning two episodes.

    Args:
        dropped: (K,) bool per observation, in time order within each episode.
        episode: (K,) episode id per observation (contiguous blocks); None for one episode.
    """
    d = np.asarray(dropped, dtype=bool).reshape(-1)
    ep = np.zeros(d.size, dtype=np.int64) if episode is None else np.asarray(episode).reshape(-1)
    if ep.shape != d.shape:
        raise ValueError(f"episode must have one id per observation ({d.size}), got shape {ep.shape}")
    runs: list[int] = []
    length = 0
    for i in range(d.size):
        if i > 0 and ep[i] != ep[i - 1] and length:
            runs.append(length)
            length = 0
        if d[i]:
            length += 1
        elif length:
            runs.append(length)
            length = 0
    if length:
        runs.append(length)
    return runs


def _records(values: ArrayLike, name: str) -> NDArray[np.float64]:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must be (K, 3), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(
            f"{name} must be finite everywhere ({int(np.sum(~np.isfinite(arr)))} non-finite values)"
        )
    return arr


def _fit_bias_latency(
    err: NDArray[np.float64], vel: NDArray[np.float64]
) -> tuple[NDArray[np.float64], float]:
    """Least squares of ``err[i, a] = bias[a] - latency * vel[i, a]``; latency clipped to >= 0."""
    n = err.shape[0]
    if float(np.sum(vel**2)) < 1e-12:
        return err.mean(axis=0), 0.0  # the point never moved: latency is not observable
    design = np.zeros((3 * n, 4))
    for a in range(3):
        design[a::3, a] = 1.0
    design[:, 3] = -vel.reshape(-1)
    coef, *_ = np.linalg.lstsq(design, err.reshape(-1), rcond=None)
    latency = float(coef[3])
    if latency <= 0.0:
        return err.mean(axis=0), 0.0
    return coef[:3], latency


def _fit_speed_std(
    residual: NDArray[np.float64], speed: NDArray[np.float64]
) -> tuple[NDArray[np.float64], float]:
    """Non-negative fit of ``sqrt(pi/2) |residual[i, a]| = std0[a] + gain * speed[i]``."""
    n = residual.shape[0]
    design = np.zeros((3 * n, 4))
    for a in range(3):
        design[a::3, a] = 1.0
    design[:, 3] = np.repeat(speed, 3)
    coef, _ = nnls(design, _ABS_TO_STD * np.abs(residual).reshape(-1))
    return coef[:3], float(coef[3])
