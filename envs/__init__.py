"""rl_jax environments: a functional JAX env API, wrappers, and the registered envs.

``import envs`` also registers every id with gymnasium (``gymnasium.make`` and
``gymnasium.make_vec(..., vectorization_mode="vector_entry_point")``). The other way round,
``envs.from_gymnasium(id_or_env)`` makes any gymnasium env one of ours
(``envs.adapters.gymnasium_host``).
"""

from envs.adapters import external_ids as _external_ids  # noqa: F401  (resolves MODULE:ID)
from envs.adapters.gym_adapter import register_with_gymnasium
from envs.adapters.gymnasium_host import from_gymnasium
from envs.core.core import Environment, EnvParams, EnvState, TimeStep
from envs.core.registry import (
    UnknownEnvError,
    make,
    parse_keywords,
    register,
    registered_ids,
)
from envs.core.spaces import Box, Discrete, Space
from envs.core.wrappers import (
    AutoReset,
    DiscretizeActions,
    EpisodeStatistics,
    FlattenObservation,
    RescaleAction,
    Wrapper,
)

register_with_gymnasium()

__all__ = [
    "AutoReset",
    "Box",
    "Discrete",
    "DiscretizeActions",
    "EnvParams",
    "EnvState",
    "Environment",
    "EpisodeStatistics",
    "FlattenObservation",
    "from_gymnasium",
    "RescaleAction",
    "Space",
    "TimeStep",
    "UnknownEnvError",
    "Wrapper",
    "make",
    "parse_keywords",
    "register",
    "registered_ids",
]
