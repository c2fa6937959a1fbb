"""REINFORCE on the MuJoCo inverted double pendulum (rl_jax/InvertedDoublePendulum-v5).

Same learner as reinforce_pendulum.py; the double pendulum is much harder for a Monte-Carlo
policy gradient, so the recipe (rl_jax.reinforce.RECIPES) uses a wider 64x64 tanh network, a
learned value baseline and normalised returns. Not tuned to a target return: treat the result
as a baseline to improve on (e.g. with --num-envs, --learning-rate, --gamma).

examples:
  python experiments/reinforce_double_pendulum.py --seeds 3
  python experiments/reinforce_double_pendulum.py --total-steps 5000000 --gif
"""

from rl_jax import cli
from rl_jax.reinforce import reinforce

if __name__ == "__main__":
    cli.main(reinforce, "rl_jax/InvertedDoublePendulum-v5", __doc__, seeds=3, total_steps=5_000_000)
