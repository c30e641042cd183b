"""Training, evaluation and learning curves for the DynDLO tasks (stable-baselines3 PPO and SAC)."""

from dyndlo_vision.learning.config import TASK_NAMES, RunConfig, env_id, load_hyperparams

__all__ = ["TASK_NAMES", "RunConfig", "env_id", "load_hyperparams"]
