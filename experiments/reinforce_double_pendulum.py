"""REINFORCE on the MuJoCo inverted double pendulum (rl_jax/InvertedDoublePendulum-v5).

Same learner as reinforce_pendulum.py; the double pendulum is much harder for a Monte-Carlo
policy gradient, so the recipe (in rl_jax.agents.reinforce) uses 32 episodes per update, a
64x64 tanh policy with a small state-free std (0.2 at the start), a learned value baseline on its
own 64x64 torso, standardised observations and returns, and gradients clipped to norm 0.5. The
learning rate (1.5e-3) decays linearly to 0 over 300 updates, the default budget (9.6M step slots =
300 updates x 32 episodes x 1,000 slots); with another --total-steps set --lr-decay-updates to
total_steps / 32,000. Envs whose episode ended wait unstepped for the others (step_active).

examples:
  python experiments/reinforce_double_pendulum.py --seeds 3
  python experiments/reinforce_double_pendulum.py --total-steps 5000000 --gif
"""

from rl_jax.agents.reinforce import reinforce
from rl_jax.run import cli

if __name__ == "__main__":
    env_id = "rl_jax/InvertedDoublePendulum-v5"
    cli.main(reinforce, env_id, __doc__, seeds=5, total_steps=9_600_000)
