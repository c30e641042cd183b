"""The tracking parameters, defined once: the Kalman filter's defaults and the control loop's tuned values.

Every other place (``dyndlo-vision track``, ``control.sim_perception``, the benchmarks) derives its filter
settings from here. This module imports nothing heavy, so a command can show the defaults in its ``--help``
without loading OpenCV, SciPy or filterpy.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

__all__ = ["FilterParams", "LATENT_LOOP_FILTER", "LOOP_FILTER", "TRACK_FILTER"]


@dataclass(frozen=True)
class FilterParams:
    """Parameters of the constant-velocity filter, in world units (metres, seconds).

    The defaults are for a cable tracked at 25 Hz by a camera about a metre away; they are what
    ``dyndlo-vision track`` uses (times :meth:`scaled` in pixel mode).

    Attributes:
        sigma_accel: Std of the white acceleration driving the model (m/s^2). A whipped cable tip accelerates
            at tens to hundreds of m/s^2; lower values smooth more and lag more. 20 keeps a 40 ms prediction
            usable on a whipped tip (the fastest whips exceed it, get gated and re-initialise); the loop's
            tuned values are :data:`LOOP_FILTER` and :data:`LATENT_LOOP_FILTER`.
        sigma_meas: Std of the position measurement noise per axis (m): the 1-2 px error of a centreline node
            at about 400-500 px per metre.
        gate_prob: Probability mass of the chi-square(3) gate; measurements outside are outliers (0.997 ->
            squared Mahalanobis distance 13.9, a 3-sigma gate).
        max_coast_s: After this long without an accepted measurement a node is lost: 0.3 s is 7 missed frames
            at 25 Hz, beyond which a constant-velocity prediction of a swinging cable is no estimate.
        init_speed_sigma: Std of the unknown velocity at initialisation (m/s): a held cable's points move at
            up to a few m/s.
        history_s: How far back out-of-order measurements are replayed (s): well beyond any camera latency
            the loop accepts (0.25 s).
        reinit_speed: Two consecutive gated measurements closer than this speed (m/s) re-initialise the node:
            faster than any cable point moves, so two agreeing measurements are the target, not outliers.
        accel_psd: When given, the process noise is a *continuous* white acceleration of this spectral
            density (m^2/s^3) instead of :attr:`sigma_accel`'s piecewise-constant one. Why: a filter that
            follows every measurement (large process noise) tends, with the piecewise-constant model, to
            the alpha-beta gains alpha = 1, beta = 2, whose velocity estimate oscillates undamped (each
            velocity is twice the last step's finite difference minus the previous velocity): a missed frame
            is then bridged with a velocity several m/s off. The continuous model's gains tend to beta =
            1.27, a damped velocity.
    """

    sigma_accel: float = 20.0
    sigma_meas: float = 0.003
    gate_prob: float = 0.997
    max_coast_s: float = 0.3
    init_speed_sigma: float = 2.0
    history_s: float = 0.5
    reinit_speed: float = 10.0
    accel_psd: float | None = None

    def __post_init__(self) -> None:
        if not (self.sigma_accel > 0 and self.sigma_meas > 0):
            raise ValueError(
                f"sigma_accel and sigma_meas must be > 0, got {self.sigma_accel}, {self.sigma_meas}"
            )
        if not 0 < self.gate_prob < 1:
            raise ValueError(f"gate_prob must be in (0, 1), got {self.gate_prob}")
        for name in ("max_coast_s", "init_speed_sigma", "reinit_speed"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not self.history_s >= 0:
            raise ValueError(f"history_s must be >= 0, got {self.history_s}")
        for name in ("sigma_accel", "sigma_meas", "gate_prob", "max_coast_s", "init_speed_sigma", "history_s",
                     "reinit_speed"):
            object.__setattr__(self, name, float(getattr(self, name)))
        if self.accel_psd is not None:
            if not self.accel_psd > 0:
                raise ValueError(f"accel_psd must be > 0 (or None), got {self.accel_psd}")
            object.__setattr__(self, "accel_psd", float(self.accel_psd))

    def scaled(self, units_per_metre: float) -> FilterParams:
        """The same filter in other length units (e.g. pixels): every length-carrying parameter times
        ``units_per_metre``; probabilities and times unchanged."""
        k = float(units_per_metre)
        return replace(
            self,
            sigma_accel=self.sigma_accel * k,
            sigma_meas=self.sigma_meas * k,
            init_speed_sigma=self.init_speed_sigma * k,
            reinit_speed=self.reinit_speed * k,
            accel_psd=None if self.accel_psd is None else self.accel_psd * k * k,
        )


#: The simulated control loop's tip filter (``control.sim_perception.tracked_state``) on a camera without
#: latency. A whipped tip accelerates at hundreds of m/s^2: with the default 20 m/s^2 fast measurements are
#: gated out and the estimate coasts off; at 2000 m/s^2 it follows the measurements and bridges missed
#: frames. That process noise is continuous
#: (:attr:`FilterParams.accel_psd` = 2000^2 x 0.04: the same velocity variance per 40 ms frame), so that a
#: missed frame is bridged with a damped velocity, not an oscillating one.
LOOP_FILTER = FilterParams(sigma_accel=2000.0, accel_psd=2000.0**2 * 0.04)
#: The loop's tip filter behind a camera latency (``max_coast_s`` is then lengthened by the latency). The
#: filter must predict across the delay, and a constant-velocity model predicts a whip badly: a small
#: sigma_accel errs less there than 2000 does (docs/results.md, "The loop").
LATENT_LOOP_FILTER = FilterParams(sigma_accel=20.0)
#: ``dyndlo-vision track``'s filter (and :class:`~dyndlo_vision.tracking.pipeline.PipelineConfig`'s default):
#: a whipped tip's acceleration at the frame rate, measured on the simulator's whips, with a continuous white
#: acceleration so that a missed frame is bridged with a damped velocity (see :data:`LOOP_FILTER`).
TRACK_FILTER = FilterParams(sigma_accel=2000.0, accel_psd=2000.0**2 * 0.04, reinit_speed=30.0)
