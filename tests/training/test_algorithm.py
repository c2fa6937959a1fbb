"""The optional hooks of the learner contract: what the run machinery asks of any learner, with
the default each gets. A learner without the ``OptionalHooks`` base (a module, an object of a
class of its own) is seen through ``hooks()``: its own hooks where it defines them, the defaults
for the rest."""

import dataclasses
import types

import pytest

from rl_jax import envs
from rl_jax.agents.dqn import dqn
from rl_jax.agents.ppo import ppo
from rl_jax.agents.td3 import td3
from rl_jax.training.algorithm import HOOKS, OptionalHooks, hooks
from rl_jax.training.recipes import Recipe, Recipes

PENDULUM = "rl_jax/Pendulum-v1"


@dataclasses.dataclass(frozen=True)
class Bare:
    """A config with nothing but what the contract needs: no make_env, no num_envs."""

    env_id: str = PENDULUM
    iterations_per_chunk: int = 3


@dataclasses.dataclass(frozen=True)
class Counted(Bare):
    num_envs: int = 4

    def make_env(self) -> envs.Environment:
        return envs.make("rl_jax/CartPole-v1")


def test_a_learner_without_the_base_gets_every_default():
    learner = hooks(types.SimpleNamespace(name="plain"))
    assert isinstance(learner, OptionalHooks)
    assert learner.policy_fields is None and learner.ranges == {}
    assert learner.recipe(PENDULUM).name == "default"
    assert learner.warm_up_steps(Bare()) == 0
    assert learner.replay_capacity(Bare()) is None
    assert learner.loop_seeds(Bare()) is False
    assert learner.validate(Bare(), None) is None
    # a config's own env and num_envs where it has them, else the registered env and nothing
    assert learner.envs_per_seed(Bare()) is None and learner.envs_per_seed(Counted()) == 4
    assert learner.env_steps_per_chunk(Counted()) == 12
    assert learner.make_env(Bare()).action_space().shape == (1,)  # the pendulum's torque
    assert isinstance(learner.make_env(Counted()).action_space(), envs.Discrete)
    assert not any(learner.defines_hook(name) for name in HOOKS)


def test_a_learner_without_the_base_keeps_its_own_hooks():
    recipes = Recipes(Recipe("default", "its own", config={"iterations_per_chunk": 7}))
    own = types.SimpleNamespace(
        name="own",
        policy_fields=("params",),
        recipes=recipes,
        warm_up_steps=lambda config: 100,
        replay_capacity=lambda config: 1_000,
        envs_per_seed=lambda config: 2,
    )
    learner = hooks(own)
    assert learner.policy_fields == ("params",)
    assert learner.recipe(PENDULUM).config == {"iterations_per_chunk": 7}
    assert (learner.warm_up_steps(Bare()), learner.replay_capacity(Bare())) == (100, 1_000)
    assert learner.envs_per_seed(Counted()) == 2
    assert learner.loop_seeds(Bare()) is False  # not its own: the default
    assert learner.defines_hook("recipes") and not learner.defines_hook("make_env")
    with pytest.raises(ValueError, match="'num_envs' is not an optional hook"):
        learner.defines_hook("num_envs")


def test_a_learner_with_the_base_is_its_own_hooks():
    assert hooks(td3) is td3 and hooks(ppo) is ppo


def test_off_policy_learners_say_their_warm_up_and_replay():
    config = td3.default_config(PENDULUM)
    assert hooks(td3).warm_up_steps(config) == config.learning_starts > 0
    assert hooks(td3).replay_capacity(config) == config.buffer_size
    assert hooks(td3).envs_per_seed(config) == config.num_envs
    assert td3.defines_hook("warm_up_steps") and not td3.defines_hook("env_steps_per_chunk")
    # PPO: no warm-up, no replay
    config = ppo.default_config("rl_jax/CartPole-v1")
    assert (ppo.warm_up_steps(config), ppo.replay_capacity(config)) == (0, None)


def test_dqn_loops_its_seeds_on_frames_only():
    assert dqn.loop_seeds(dqn.default_config("rl_jax/CartPolePixels-v1"))
    assert not dqn.loop_seeds(dqn.default_config("rl_jax/CartPole-v1"))
