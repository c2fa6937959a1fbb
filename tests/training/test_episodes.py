"""The spaces a learner sizes its networks by: those of the env its policy acts in."""

from rl_jax import envs
from rl_jax.agents.dqn import PixelConfig, dqn
from rl_jax.agents.ppo import ppo
from rl_jax.training import episodes


def test_spaces_are_those_of_the_env_the_policy_acts_in():
    vector = ppo.default_config("rl_jax/Pendulum-v1")
    env = episodes.make_eval_env(vector)
    assert episodes.action_space(vector) == env.action_space()
    assert episodes.observation_space(vector) == env.observation_space()
    assert isinstance(episodes.action_space(vector), envs.Box)
    # a network that reads images sees them as frames, every other one a flat vector
    pixels = dqn.default_config("rl_jax/CartPolePixels-v1")
    assert isinstance(pixels, PixelConfig)
    assert len(episodes.observation_space(pixels).shape) == 3
    assert isinstance(episodes.action_space(pixels), envs.Discrete)
