"""DQN on rl_jax/CartPole-v1, all seeds as one compiled program.

The recipe is rl_jax.agents.dqn.RECIPES["rl_jax/CartPole-v1"]: a 256x256 Q-network, Adam 1e-3, Huber
loss, batch 64, 4 envs with one gradient update per 2 env steps, a hard target copy every 100
updates, epsilon falling from 1 to 0.04 over the first 8,000 env steps, and the rate falling
linearly to 0 by 40,000 env steps: the greedy policy reaches 500 near 30-45k steps, and a rate
that stays up keeps knocking it off again (measured in the recipe's comment). Every run also
keeps each seed's best evaluated policy (RUN_DIR/best/), which render and --gif show. The
options are flags: --double, --dueling, --n-step 3, --prioritized (with --priority-alpha,
--priority-beta-start, --priority-beta-steps).

examples:
  python experiments/dqn_cartpole.py --seeds 3
  python experiments/dqn_cartpole.py --double --dueling --n-step 3 --prioritized --gif
  python experiments/dqn_cartpole.py --resume runs/<dir> --total-steps 100000
"""

from rl_jax.agents.dqn import dqn
from rl_jax.run import cli

if __name__ == "__main__":
    cli.main(dqn, "rl_jax/CartPole-v1", __doc__, seeds=3, total_steps=60_000)
