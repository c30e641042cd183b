"""The student: a stable-baselines3 PPO policy whose mean action is regressed onto the expert's labels, so
that the result is an ordinary PPO zip that ``policies.load``, ``evaluate`` and the control loop take."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from dyndlo_vision.learning.distill.collection import Episodes

__all__ = ["new_student", "fit_student"]


def new_student(env: Any, net_arch: Sequence[int], seed: int) -> Any:
    """A PPO model whose policy will be fitted (observation -> mean action); log std starts at -2."""
    from stable_baselines3 import PPO

    kwargs = {"net_arch": {"pi": list(net_arch), "vf": [64, 64]}, "log_std_init": -2.0}
    return PPO("MlpPolicy", env, policy_kwargs=kwargs, seed=seed, device="cpu", verbose=0)


def fit_student(
    model: Any,
    data: Episodes,
    epochs: int = 300,
    batch_size: int = 256,
    lr: float = 1e-3,
    validation_fraction: float = 0.1,
    seed: int = 0,
    on_epoch: Callable[[int, float], Any] | None = None,
) -> dict[str, float]:
    """Regress the PPO policy's mean action onto the expert's actions (mean squared error, Adam, cosine lr).

    Whole episodes (by seed) are held out for validation (none when there is only one episode). Returns the
    final training and validation loss (NaN without validation episodes). ``on_epoch`` is called with the
    epoch's index and training loss after every epoch (e.g. for a progress bar).
    """
    import torch

    rng = np.random.default_rng(seed)
    episodes = np.unique(data.seeds)
    n_held = max(1, int(len(episodes) * validation_fraction)) if len(episodes) > 1 else 0  # keep one to train
    held = set(rng.choice(episodes, size=n_held, replace=False))
    val = np.isin(data.seeds, list(held))
    obs = torch.as_tensor(data.observations, dtype=torch.float32)
    act = torch.as_tensor(data.actions, dtype=torch.float32)
    train_idx = np.flatnonzero(~val)
    policy = model.policy
    params = [*policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters()]
    optimiser = torch.optim.Adam(params, lr=lr)
    steps = epochs * max(1, int(np.ceil(len(train_idx) / batch_size)))
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=steps, eta_min=lr * 0.05)

    def mean_action(x: torch.Tensor) -> torch.Tensor:
        features = policy.extract_features(x, policy.pi_features_extractor)
        return policy.action_net(policy.mlp_extractor.forward_actor(features))

    policy.set_training_mode(True)
    train_loss = float("nan")
    for epoch in range(epochs):
        order = rng.permutation(train_idx)
        total = 0.0
        for start in range(0, len(order), batch_size):
            batch = torch.as_tensor(order[start : start + batch_size])
            loss = torch.mean((mean_action(obs[batch]) - act[batch]) ** 2)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            total += float(loss.detach()) * len(batch)
        train_loss = total / len(order)
        if on_epoch is not None:
            on_epoch(epoch, train_loss)
    policy.set_training_mode(False)
    with torch.no_grad():
        val_loss = float(torch.mean((mean_action(obs[val]) - act[val]) ** 2)) if val.any() else float("nan")
    return {"train_mse": train_loss, "validation_mse": val_loss}
