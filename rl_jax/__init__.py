"""rl_jax: pure-functional TD3, DDPG, DQN and REINFORCE, jit-compiled with vmapped envs."""

__version__ = "0.1.0"
