"""A policy's deterministic action as a NumPy forward pass, for the control loop.

stable-baselines3's ``model.predict`` converts the observation to a tensor, checks its shape, runs torch and
converts back: about 0.3-0.5 ms for one 12-number observation here, most of it outside the network. The
loop asks for one action every 40 ms and wants that time back, so :func:`deterministic_policy` reads the
actor's weights once and computes the same action with NumPy matrix products (float32, as torch does).

Supported: PPO and A2C policies with a Box action space (the Gaussian's mean, clipped to the space) and
SAC policies (tanh of the mean, rescaled to the space), both with a flatten feature extractor and an MLP of
Linear layers with ReLU or Tanh. Anything else (another extractor, state-dependent exploration, a
recurrent policy) keeps ``model.predict``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: torch activation class names -> their NumPy forms.
_ACTIVATIONS: dict[str, Callable[[NDArray[np.float32]], NDArray[np.float32]]] = {
    "ReLU": lambda x: np.maximum(x, 0.0, out=x),
    "Tanh": lambda x: np.tanh(x, out=x),
}


class NumpyActor:
    """The deterministic action of a stable-baselines3 policy, computed with NumPy.

    Args:
        layers: (weight as out x in, bias, activation name or None) per Linear layer, the action head last.
        squash: Whether the head's output goes through tanh and is rescaled from [-1, 1] to the action space
            (SAC); otherwise it is clipped to the space (PPO, A2C).
        low: The action space's lower bounds.
        high: Its upper bounds.
    """

    def __init__(
        self,
        layers: list[tuple[NDArray[np.float32], NDArray[np.float32], str | None]],
        squash: bool,
        low: NDArray[np.float32],
        high: NDArray[np.float32],
    ) -> None:
        self.layers = [
            (np.ascontiguousarray(w.T), b, None if a is None else _ACTIVATIONS[a]) for w, b, a in layers
        ]
        self.input_size = int(layers[0][0].shape[1])
        self.squash = squash
        self.low = np.asarray(low, dtype=np.float32)
        self.high = np.asarray(high, dtype=np.float32)

    @classmethod
    def from_sb3(cls, model: Any) -> NumpyActor:
        """The actor of a stable-baselines3 model (PPO, A2C or SAC; see the module docstring).

        Raises:
            ValueError: The policy has a part this forward pass does not reproduce, named.
        """
        policy = model.policy
        space = model.action_space
        if type(space).__name__ != "Box" or type(model.observation_space).__name__ != "Box":
            raise ValueError(
                f"needs Box observation and action spaces, got {model.observation_space}, {space}"
            )
        if getattr(model, "use_sde", False):
            raise ValueError("state-dependent exploration (use_sde) is not supported")
        kind = type(policy).__name__
        if kind == "SACPolicy":
            actor = policy.actor
            _check_flatten(actor.features_extractor)
            hidden, head, squash = actor.latent_pi, actor.mu, True
        elif kind in ("ActorCriticPolicy", "MlpPolicy") and hasattr(policy, "action_net"):
            _check_flatten(policy.pi_features_extractor)
            hidden, head = policy.mlp_extractor.policy_net, policy.action_net
            squash = bool(policy.squash_output)
            dist = type(policy.action_dist).__name__
            if dist != "DiagGaussianDistribution":
                raise ValueError(f"the action distribution {dist} is not supported")
        else:
            raise ValueError(f"the policy class {kind} is not supported")
        layers: list[tuple[NDArray[np.float32], NDArray[np.float32], str | None]] = []
        for module in list(hidden) + [head]:
            name = type(module).__name__
            if name == "Linear":
                w = module.weight.detach().cpu().numpy().astype(np.float32)
                b = module.bias.detach().cpu().numpy().astype(np.float32)
                layers.append((w, b, None))
            elif name in _ACTIVATIONS and layers and layers[-1][2] is None:
                layers[-1] = (layers[-1][0], layers[-1][1], name)
            else:
                raise ValueError(f"the layer {name} is not supported (Linear with ReLU or Tanh only)")
        return cls(layers, squash, space.low, space.high)

    def __call__(self, observation: Any) -> NDArray[np.float32]:
        """The action for one observation (a flat vector of the policy's input size)."""
        x = np.asarray(observation, dtype=np.float32).reshape(-1)
        if x.size != self.input_size:
            raise ValueError(
                f"expected an observation of {self.input_size} numbers, got shape {np.shape(observation)}"
            )
        for w, b, act in self.layers:
            x = x @ w
            x += b
            if act is not None:
                act(x)
        if self.squash:
            return (self.low + 0.5 * (np.tanh(x) + 1.0) * (self.high - self.low)).astype(np.float32)
        return np.clip(x, self.low, self.high)


def _check_flatten(extractor: Any) -> None:
    if type(extractor).__name__ != "FlattenExtractor":
        raise ValueError(f"the feature extractor {type(extractor).__name__} is not supported (flatten only)")


def deterministic_policy(model: Any) -> Callable[[Any], NDArray[np.float32]]:
    """``observation -> action``, as ``model.predict(observation, deterministic=True)[0]`` gives it, through
    :class:`NumpyActor` where it reproduces the model, else through ``model.predict``.

    A :class:`~dyndlo_vision.policies.HistoryPolicy` keeps its P_DLO history: its features are appended to
    each observation before the forward pass, as its ``predict`` does.
    """
    sb3 = getattr(model, "sb3_model", model)
    try:
        actor = NumpyActor.from_sb3(sb3)
    except (ValueError, AttributeError):
        return lambda obs: np.asarray(model.predict(obs, deterministic=True)[0])
    if sb3 is not model:
        return lambda obs: actor(model.student_input(obs))
    return actor
