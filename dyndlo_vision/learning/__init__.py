"""Training, evaluation and learning curves for the DynDLO tasks (stable-baselines3 PPO and SAC)."""

from dyndlo_vision.learning.config import RunConfig, load_hyperparams

__all__ = ["RunConfig", "load_hyperparams"]
