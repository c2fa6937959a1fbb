"""DQN on the 1-D rocket (rl_jax/Rocket-v0) with thrust discretised to {-1, 0, +1}.

The rocket's continuous thrust goes through envs.DiscretizeActions with --action-bins values
(3: full thrust either way, or none). Recipe: rl_jax.agents.dqn's "rl_jax/Rocket-v0"
(CartPole's network and loop, epsilon decaying over 50,000 env steps). Episodes last up to 500
steps; the goal tolerance is tight, so a good policy mostly earns the shaping reward for approaching
the origin slowly. --gif renders the final policy with its x(t), v(t) plot.

examples:
  python experiments/dqn_rocket.py --seeds 3
  python experiments/dqn_rocket.py --action-bins 5 --double --n-step 3 --gif
"""

from rl_jax.agents.dqn import dqn
from rl_jax.run import cli

if __name__ == "__main__":
    cli.main(dqn, "rl_jax/Rocket-v0", __doc__, seeds=3, total_steps=200_000)
