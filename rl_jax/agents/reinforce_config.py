"""REINFORCE's settings: the static ``Config`` and the ``Hyperparams`` a sweep varies. Apart from
the learner so that its parts (``reinforce_policy``) can import them.
"""

from __future__ import annotations

import dataclasses

from flax import struct
from jax.typing import ArrayLike

from rl_jax import envs
from rl_jax.training import networks, params

BASELINES = ("none", "mean", "value")


@dataclasses.dataclass(frozen=True, kw_only=True)
class Config:
    """Static settings of REINFORCE (changing one recompiles)."""

    env_id: str
    num_envs: int = 16  # episodes per update, collected by vmapped envs
    iterations_per_chunk: int = 20  # updates per compiled call; eval after each chunk
    num_eval_envs: int = 10  # episodes of the deterministic policy per evaluation
    hidden: tuple[int, ...] = (16, 32)  # the policy's torso
    activation: str = "tanh"  # see rl_jax.training.networks.ACTIVATIONS
    baseline: str = "none"  # "none", "mean" (batch mean of returns) or "value" (learned)
    normalize_returns: bool = False  # standardise the returns over each batch
    std_floor: float = 1e-6  # Gaussian policy: the std's lower bound
    std_mode: str = "state"  # Gaussian std: "state" (a head) or "param" (learned, state-free)
    initial_std: float = 1.0  # with std_mode "param": the std before training
    value_hidden: tuple[int, ...] = ()  # baseline "value": its own torso (empty: shares policy's)
    normalize_obs: bool = False  # standardise observations by running mean and variance
    network_init: str = "fan_in_uniform"  # see rl_jax.training.networks
    squash_mean: bool = False  # Gaussian policy: the mean is tanh-squashed into the action bounds
    # the env's constructor keywords, "name=value, name=value": envs.make(env_id, **them)
    env_kwargs: str = ""

    def __post_init__(self) -> None:
        envs.parse_keywords(self.env_kwargs)  # a ValueError names what is wrong
        for name in ("num_envs", "iterations_per_chunk", "num_eval_envs"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.baseline not in BASELINES:
            raise ValueError(f"baseline must be one of {BASELINES}, got {self.baseline!r}")
        if self.activation not in networks.ACTIVATIONS:
            raise ValueError(f"activation must be one of {list(networks.ACTIVATIONS)}")
        if self.std_mode not in ("state", "param"):
            raise ValueError(f"std_mode must be 'state' or 'param', got {self.std_mode!r}")
        if self.initial_std <= 0.0:
            raise ValueError(f"initial_std must be > 0, got {self.initial_std}")
        if self.std_floor <= 0.0:
            raise ValueError(f"std_floor must be > 0, got {self.std_floor}")
        if self.network_init not in networks.INITS:
            raise ValueError(f"network_init must be one of {networks.INITS}")

    def make_env(self) -> envs.Environment:
        return envs.make(self.env_id, **envs.parse_keywords(self.env_kwargs))


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling. Defaults: gymnasium's REINFORCE tutorial."""

    learning_rate: ArrayLike = 1e-4  # AdamW step size
    weight_decay: ArrayLike = 0.01  # AdamW's decoupled weight decay (torch's default)
    gamma: ArrayLike = 0.99  # discount of the reward-to-go
    value_coef: ArrayLike = 0.5  # weight of the value head's loss (baseline "value")
    entropy_coef: ArrayLike = 0.0  # weight of the policy's mean entropy, subtracted from the loss
    max_grad_norm: ArrayLike = 0.0  # clip the gradient's global norm to this (0: no clipping)
    lr_decay_updates: ArrayLike = 0.0  # updates for the rate to fall linearly to 0 (0: constant)
