"""rl_jax environments: a functional JAX env API, wrappers, and the registered envs.

Imported as ``rl_jax.envs`` (``from rl_jax import envs``): the repository keeps the package in
its top-level ``envs/`` folder, but an installed rl_jax claims no top-level name but its own.
Importing it also registers every id with gymnasium (``gymnasium.make`` and
``gymnasium.make_vec(..., vectorization_mode="vector_entry_point")``). The other way round,
``envs.from_gymnasium(id_or_env)`` makes any gymnasium env one of ours
(``envs.adapters.gymnasium_host``), and ``envs.from_gymnax(name)`` any gymnax env
(``envs.adapters.gymnax_adapter``) and ``envs.from_atari(game)`` any ALE game with DQN's
preprocessing (``envs.adapters.atari``).
"""

if __name__ == "envs":  # the folder imported by its own name, from a checkout's root
    raise ImportError(
        "rl_jax's environments are the package rl_jax.envs: write `from rl_jax import envs`"
    )

from rl_jax.envs.adapters import external_ids as _external_ids  # noqa: F401  (resolves MODULE:ID)
from rl_jax.envs.adapters.atari import from_atari  # imports ale-py on its first call
from rl_jax.envs.adapters.gym_adapter import register_with_gymnasium
from rl_jax.envs.adapters.gymnasium_host import from_gymnasium
from rl_jax.envs.adapters.gymnax_adapter import from_gymnax  # imports gymnax on its first call
from rl_jax.envs.core.core import Environment, EnvParams, EnvState, TimeStep
from rl_jax.envs.core.preprocessing import (
    ClipReward,
    EpisodicLife,
    FrameSkip,
    FrameStack,
    SignReward,
    StickyActions,
    TransformReward,
    action_mask,
    has_action_mask,
    reset_after,
)
from rl_jax.envs.core.registry import (
    ATARI_IDS,
    MINATAR_IDS,
    UnknownEnvError,
    make,
    parse_keywords,
    register,
    registered_ids,
)
from rl_jax.envs.core.spaces import Box, Discrete, Space
from rl_jax.envs.core.wrappers import (
    AutoReset,
    DiscretizeActions,
    EpisodeStatistics,
    FlattenObservation,
    MaskObservation,
    RescaleAction,
    Wrapper,
)

register_with_gymnasium()

__all__ = [
    "AutoReset",
    "Box",
    "ClipReward",
    "Discrete",
    "DiscretizeActions",
    "EnvParams",
    "EnvState",
    "Environment",
    "EpisodeStatistics",
    "EpisodicLife",
    "FlattenObservation",
    "FrameSkip",
    "FrameStack",
    "from_atari",
    "from_gymnasium",
    "from_gymnax",
    "MaskObservation",
    "RescaleAction",
    "SignReward",
    "Space",
    "StickyActions",
    "TimeStep",
    "TransformReward",
    "UnknownEnvError",
    "Wrapper",
    "action_mask",
    "has_action_mask",
    "make",
    "parse_keywords",
    "register",
    "ATARI_IDS",
    "MINATAR_IDS",
    "registered_ids",
    "reset_after",
]
