"""Learners whose chunks take more env steps than they plan, for the budget tests: the fake
learner (``fake_algorithm``), reporting ``FACTOR`` times its env steps, as an on-policy learner
written without ``env_steps_per_chunk`` does (its chunk takes ``num_envs * num_steps *
iterations_per_chunk`` env steps; the default hook plans ``num_envs * iterations_per_chunk``).

``learner`` overruns from its first chunk; ``late`` reports its first ``GOOD_CHUNKS`` chunks as
planned and overruns after them (what a run has saved by then must stay).
"""

from __future__ import annotations

import fake_algorithm as fake
import jax.numpy as jnp

from rl_jax.training.algorithm import ChunkMetrics

FACTOR = 4
GOOD_CHUNKS = 2


class Overrunning:
    """The fake learner without its ``env_steps_per_chunk``, taking ``FACTOR`` times the planned
    env steps per chunk from chunk ``good_chunks + 1`` on."""

    policy_fields = fake.policy_fields

    def __init__(self, name: str, good_chunks: int = 0) -> None:
        self.name = name
        self.good_chunks = good_chunks

    def default_config(self, env_id: str = fake.ENV_ID) -> fake.Config:
        return fake.default_config(env_id)

    def default_hyperparams(self, env_id: str | None = None) -> fake.Hyperparams:
        return fake.default_hyperparams(env_id)

    def make_env(self, config: fake.Config):
        return fake.make_env(config)

    def init(self, key, config: fake.Config, hparams: fake.Hyperparams) -> fake.TrainState:
        return fake.init(key, config, hparams)

    def train_chunk(
        self, state: fake.TrainState, config: fake.Config, hparams: fake.Hyperparams
    ) -> tuple[fake.TrainState, ChunkMetrics]:
        state, metrics = fake.train_chunk(state, config, hparams)
        planned = config.num_envs * config.iterations_per_chunk
        after = self.good_chunks * planned  # the env steps reported as planned
        steps = metrics.env_steps
        overrun = jnp.where(steps > after, after + (steps - after) * FACTOR, steps)
        return state, metrics._replace(env_steps=overrun)

    def policy(self, state: fake.TrainState, config: fake.Config):
        return fake.policy(state, config)


learner = Overrunning("overrunning")
late = Overrunning("overrunning_late", good_chunks=GOOD_CHUNKS)
