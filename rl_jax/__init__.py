"""rl_jax: pure-functional TD3, DDPG, DQN and REINFORCE, jit-compiled with vmapped envs."""

import os

# XLA's C++ runtime logs a warning on every persistent-cache hit ("Assume version
# compatibility"); it must be silenced before jax is imported. Set the variable to override.
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

__version__ = "0.1.0"
