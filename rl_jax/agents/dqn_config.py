"""DQN's settings: the static ``Config`` (``PixelConfig`` for envs seen as frames) and the
``Hyperparams`` a sweep varies. Apart from the learner so that its parts (``dqn_replay``) can
import them.
"""

from __future__ import annotations

import dataclasses

from flax import struct
from jax.typing import ArrayLike

from rl_jax import envs
from rl_jax.training import conv, networks, params
from rl_jax.training.episodes import ImageObservations
from rl_jax.training.offpolicy import OffPolicyConfig


@dataclasses.dataclass(frozen=True, kw_only=True)
class Config(OffPolicyConfig):
    """Static settings of DQN (the loop's are in ``OffPolicyConfig``)."""

    hidden: tuple[int, ...] = (120, 84)  # hidden ReLU layers of the Q-network
    double: bool = False  # Double DQN targets: the online net's argmax, valued by the target net
    dueling: bool = False  # dueling head: q = v + a - mean(a)
    n_step: int = 1  # rewards summed before bootstrapping (a window stops at an episode's end)
    prioritized: bool = False  # proportional prioritized replay with importance weights
    target_update_period: int = 500  # gradient updates between target steps of size tau
    action_bins: int = 3  # values per action dim when the env's actions are continuous
    network_init: str = "fan_in_uniform"  # see rl_jax.training.networks
    norm: str = "none"  # "layer": LayerNorm before each hidden ReLU of the Q-network
    # TD7's policy checkpoints (rl_jax.training.policy_checkpoints): the training envs act
    # (epsilon-greedily) with a frozen copy of the Q-network for an assessment of
    # checkpoint_episodes episodes (1 before env step checkpoint_episodes_from); if none returned
    # less than the checkpoint's score, the copy becomes the checkpoint, whose greedy policy is
    # what evaluation, best/ and loaded policies use. Updates go on meanwhile.
    policy_checkpoints: bool = False
    checkpoint_episodes: int = 20  # policy_checkpoints: episodes per assessment (TD7: 20)
    checkpoint_episodes_from: int = 750_000  # policy_checkpoints: env step of the switch

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.norm not in ("none", "layer"):
            raise ValueError(f"norm must be 'none' or 'layer', got {self.norm!r}")
        if self.n_step < 1 or self.target_update_period < 1:
            raise ValueError("n_step and target_update_period must be >= 1")
        if self.checkpoint_episodes < 1 or self.checkpoint_episodes_from < 0:
            raise ValueError("checkpoint_episodes must be >= 1, checkpoint_episodes_from >= 0")
        if self.action_bins < 2:
            raise ValueError(f"action_bins must be >= 2, got {self.action_bins}")
        if self.network_init not in networks.INITS:
            raise ValueError(f"network_init must be one of {networks.INITS}")

    def make_env(self) -> envs.Environment:
        """The registered env; a continuous one with its actions discretised."""
        env = super().make_env()
        if isinstance(env.action_space(), envs.Box):
            env = envs.DiscretizeActions(env, self.action_bins)
        return env


#: Envs observed as stacked frames: their config is a ``PixelConfig``.
PIXEL_ENVS = ("rl_jax/CartPolePixels-v1",)


@dataclasses.dataclass(frozen=True, kw_only=True)
class PixelConfig(Config, ImageObservations):
    """DQN on frames (``PIXEL_ENVS``): the frame geometry and a conv torso before ``hidden``.

    The replay keeps each frame once per step and rebuilds stacks when sampling
    (``rl_jax.training.frame_replay``). The default torso is the 2013 DQN paper's (16 8x8/4, 32
    4x4/2, then 256 units), not Nature DQN's (32 8x8/4, 64 4x4/2, 64 3x3/1, 512): its gradient
    step costs about a third as much on a CPU, and CartPole's frames are simple."""

    hidden: tuple[int, ...] = (256,)  # hidden ReLU layers after the conv torso
    frame_size: int = 84  # frames are frame_size x frame_size grayscale pixels
    frame_stack: int = 4  # the last frame_stack frames are the observation's channels
    conv_layers: tuple[int, ...] = (16, 8, 4, 32, 4, 2)  # (features, kernel, stride) per layer
    # Seeds as an unrolled loop in the one program (training.parallel.seed_loop), not a vmap:
    # XLA's CPU backend runs the conv torso's batched (vmapped) gradients slower than a loop of
    # unbatched ones.
    loop_seeds: bool = True
    # The torso sees only the rows the env ever draws on (its ``drawn_rows``; CartPole: 31 of 84,
    # grown to 36 that the conv stack reads whole). The other rows are white in every frame, so
    # the network loses nothing while its convolutions cost 36/84 as much. Off by default: runs
    # saved before it existed see the whole frame.
    crop_drawn_rows: bool = False
    # DrQ's random shifts (rl_jax.training.augment): every sampled stack, obs and next_obs
    # apart, is moved by up to augment_shift pixels in each axis (edges repeated) before the
    # Q-networks see it, in the loss only; acting and evaluation see the frames as they are.
    # DrQ used 4 at 84x84. 0: off (the update is then the same program as before it existed).
    # On CartPole's frames 4 stopped learning altogether.
    augment_shift: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.frame_size < 1 or self.frame_stack < 1:
            raise ValueError("frame_size and frame_stack must be >= 1")
        if not 0 <= self.augment_shift < self.frame_size:
            raise ValueError(
                f"augment_shift must be in 0..{self.frame_size - 1}, got {self.augment_shift}"
            )
        conv.check_conv_layers(self.conv_layers, self.frame_size)
        given = {"frame_size", "frame_stack"} & set(envs.parse_keywords(self.env_kwargs))
        if given:
            name = sorted(given)[0]
            raise ValueError(
                f"{name} is a config field here: --{name.replace('_', '-')}, not --env-kwargs"
            )
        first, stop = self.conv_rows() or (0, self.frame_size)
        conv.check_conv_layers(self.conv_layers, stop - first)

    def make_env(self) -> envs.Environment:
        return envs.make(
            self.env_id,
            frame_size=self.frame_size,
            frame_stack=self.frame_stack,
            **envs.parse_keywords(self.env_kwargs),
        )

    def conv_rows(self) -> tuple[int, ...]:
        """``(first, stop)``, the frame rows the conv torso sees, or ``()`` for all."""
        env = self.make_env()
        if not self.crop_drawn_rows or not hasattr(env, "drawn_rows"):
            return ()
        return conv.covering_rows(self.conv_layers, *env.drawn_rows(), self.frame_size)


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling. Defaults: CleanRL's classic-control DQN."""

    learning_rate: ArrayLike = 2.5e-4  # Adam step size
    lr_decay_steps: ArrayLike = 0.0  # env steps (all envs) for the rate to fall to 0 (0: constant)
    gamma: ArrayLike = 0.99  # discount
    tau: ArrayLike = 1.0  # target step every target_update_period updates (1: hard copy)
    epsilon_start: ArrayLike = 1.0  # exploration rate at env step 0
    epsilon_end: ArrayLike = 0.05  # exploration rate after epsilon_decay_steps
    epsilon_decay_steps: ArrayLike = 250_000.0  # env steps (all envs) of the linear epsilon decay
    huber_delta: ArrayLike = 1.0  # TD errors beyond this are penalised linearly, not squared
    max_grad_norm: ArrayLike = 10.0  # gradients are clipped to this global norm
    priority_alpha: ArrayLike = 0.6  # prioritized: P(i) proportional to priority_i^alpha
    priority_beta_start: ArrayLike = 0.4  # prioritized: importance-weight exponent at the start
    priority_beta_steps: ArrayLike = 500_000.0  # prioritized: env steps for beta to rise to 1
    priority_eps: ArrayLike = 1e-6  # prioritized: priority = |TD error| + eps
    # policy_checkpoints: the checkpoint's score is multiplied by this when assessments lengthen
    # to checkpoint_episodes (TD7: 0.9)
    checkpoint_reset_weight: ArrayLike = 0.9
