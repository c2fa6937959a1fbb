"""PPO's settings: the static ``Config`` (``PixelConfig`` for envs seen as frames) and the
``Hyperparams`` a sweep may vary without recompiling. Defaults: CleanRL's ``ppo.py`` for classic
control, except for the counts, which the recipes (``ppo_recipes``) set per env.
"""

from __future__ import annotations

import dataclasses

from flax import struct

from rl_jax import envs
from rl_jax.training import conv, networks, params
from rl_jax.training.episodes import ImageObservations
from rl_jax.training.params import Scalar


@dataclasses.dataclass(frozen=True, kw_only=True)
class Config:
    """Static settings (changing one recompiles)."""

    env_id: str
    num_envs: int = 8  # envs stepped together (vmapped), each with its own episode
    num_steps: int = 128  # steps of every env per rollout: a batch is num_envs * num_steps
    num_epochs: int = 4  # passes over each batch
    num_minibatches: int = 4  # gradient steps per pass (they must split the batch evenly)
    iterations_per_chunk: int = 1  # rollouts and updates per compiled call; eval after each call
    num_eval_envs: int = 10  # episodes of the deterministic policy per evaluation
    hidden: tuple[int, ...] = (
        64,
        64,
    )  # hidden layers of the actor and of the critic (each its own)
    activation: str = "tanh"  # see rl_jax.training.networks.ACTIVATIONS
    initial_std: float = 1.0  # Gaussian policy: the state-independent std before training
    normalize_obs: bool = False  # standardise observations by running mean and variance
    normalize_rewards: bool = False  # divide rewards by a running std of discounted returns
    normalize_advantages: bool = True  # standardise the advantages of each minibatch
    clip_value_loss: bool = True  # keep the value within value_clip_eps of its old value
    # the env's constructor keywords, "name=value, name=value": envs.make(env_id, **them)
    env_kwargs: str = ""

    def __post_init__(self) -> None:
        envs.parse_keywords(self.env_kwargs)  # a ValueError names what is wrong
        for name in (
            "num_envs",
            "num_steps",
            "num_epochs",
            "num_minibatches",
            "iterations_per_chunk",
            "num_eval_envs",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.batch_size % self.num_minibatches:
            raise ValueError(
                f"num_minibatches ({self.num_minibatches}) must divide the batch of num_envs x "
                f"num_steps = {self.batch_size} env steps"
            )
        if self.activation not in networks.ACTIVATIONS:
            raise ValueError(f"activation must be one of {list(networks.ACTIVATIONS)}")
        if self.initial_std <= 0.0:
            raise ValueError(f"initial_std must be > 0, got {self.initial_std}")

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.num_steps

    def make_env(self) -> envs.Environment:
        return envs.make(self.env_id, **envs.parse_keywords(self.env_kwargs))


#: Envs observed as stacked frames: their config is a ``PixelConfig``.
PIXEL_ENVS = ("rl_jax/CartPolePixels-v1",)


@dataclasses.dataclass(frozen=True, kw_only=True)
class PixelConfig(Config, ImageObservations):
    """PPO on frames (``PIXEL_ENVS``): a conv torso (``conv.ConvTorso``, DQN's) and the
    ``hidden`` layers after it are shared by actor and critic, each then one linear head (as in
    the PPO paper's Atari network). Observations are not standardised: the torso scales the
    uint8 pixels to [0, 1] itself."""

    hidden: tuple[int, ...] = (256,)
    activation: str = "relu"
    frame_size: int = 84  # frames are frame_size x frame_size grayscale pixels
    frame_stack: int = 4  # the last frame_stack frames are the observation's channels
    # (features, kernel, stride) per conv layer: the 2013 DQN paper's torso, as DQN's pixel config
    conv_layers: tuple[int, ...] = (16, 8, 4, 32, 4, 2)
    # the torso sees only the frame rows the env ever draws on (as DQN's crop_drawn_rows)
    crop_drawn_rows: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.normalize_obs:
            raise ValueError(
                "normalize_obs is for vector observations; frames are scaled to [0, 1]"
            )
        if self.frame_size < 1 or self.frame_stack < 1:
            raise ValueError("frame_size and frame_stack must be >= 1")
        conv.check_conv_layers(self.conv_layers, self.frame_size)
        first, stop = self.conv_rows() or (0, self.frame_size)
        conv.check_conv_layers(self.conv_layers, stop - first)

    def conv_rows(self) -> tuple[int, ...]:
        """``(first, stop)``, the frame rows the conv torso sees, or ``()`` for all."""
        env = self.make_env()
        if not self.crop_drawn_rows or not hasattr(env, "drawn_rows"):
            return ()
        return conv.covering_rows(self.conv_layers, *env.drawn_rows(), self.frame_size)

    def make_env(self) -> envs.Environment:
        return envs.make(
            self.env_id,
            frame_size=self.frame_size,
            frame_stack=self.frame_stack,
            **envs.parse_keywords(self.env_kwargs),
        )


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling."""

    learning_rate: Scalar = 2.5e-4  # Adam step size at the start
    lr_decay_steps: Scalar = (
        0.0  # env steps (one seed, all envs) over which it falls to 0 (0: constant)
    )
    gamma: Scalar = 0.99  # discount
    gae_lambda: Scalar = 0.95  # GAE's lambda: 0 one-step TD errors, 1 Monte-Carlo returns
    clip_eps: Scalar = 0.2  # the surrogate's ratio is clipped to [1 - clip_eps, 1 + clip_eps]
    value_clip_eps: Scalar = 0.2  # clip_value_loss: how far a value may move from its old value
    vf_coef: Scalar = 0.5  # weight of the value loss
    ent_coef: Scalar = 0.01  # weight of the policy's mean entropy, subtracted from the loss
    max_grad_norm: Scalar = 0.5  # clip the gradient's global norm to this (0: no clipping)
    adam_eps: Scalar = 1e-5  # Adam's epsilon (PPO implementations use 1e-5, not optax's 1e-8)
    reward_clip: Scalar = 10.0  # normalize_rewards: scaled rewards are clipped to +-this (0: not)
