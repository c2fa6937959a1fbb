"""DQN on rl_jax/CartPole-v1, all seeds as one compiled program.

The recipe is rl_jax.agents.dqn's "rl_jax/CartPole-v1": a 64x64 Q-network, Adam 3e-3, Huber
loss, 3-step returns, batch 64, 4 envs with one gradient update per 2 env steps, a hard target copy
every 100 updates, epsilon falling from 1 to 0.01 over the first 8,000 env steps, and TD7's policy
checkpoints: the greedy policy that evaluation, best/, --gif and load_policy use is the last copy
of the Q-network that played 20 training episodes (1 before env step 20,000) without one
scoring below the previous checkpoint's score. Without it the greedy policy keeps collapsing and
recovering after it first balances. The default budget is 60k env steps per seed. The options
are flags: --double, --dueling,
--n-step N, --prioritized (with --priority-alpha, --priority-beta-start, --priority-beta-steps),
--norm layer, --no-policy-checkpoints.

examples:
  python experiments/dqn_cartpole.py --seeds 30
  python experiments/dqn_cartpole.py --double --dueling --n-step 3 --prioritized --gif
  python experiments/dqn_cartpole.py --resume runs/<dir> --total-steps 100000
"""

from rl_jax.agents.dqn import dqn
from rl_jax.run import cli

if __name__ == "__main__":
    cli.main(dqn, "rl_jax/CartPole-v1", __doc__, seeds=3, total_steps=60_000)
