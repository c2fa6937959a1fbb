"""REINFORCE on the MuJoCo inverted pendulum (rl_jax/InvertedPendulum-v5).

The network our users started from (gymnasium's REINFORCE tutorial): two tanh layers of 16 and 32
units, a mean head and a softplus std head (std floor 1e-6 on the std), AdamW. The recipe in
rl_jax.agents.reinforce adds what makes it reliable across seeds: 16 whole episodes per
update (vmapped envs, masked after each episode's end), normalised returns and a rate of 3e-3 that
decays linearly to 0 over the default budget of 300 updates (4.8M step slots), so that the policy a
run ends with is a settled one. The logged `step` counts env step slots (16 x 1,000 per update; see
rl_jax.agents.reinforce), the real count is `env_steps_taken` in metrics.jsonl. Deeper nets:
--hidden 64,64. Baselines: --baseline mean or --baseline value. The physics backend is MuJoCo C on
CPU (set RL_JAX_MUJOCO_BACKEND=mjx for MJX).

examples:
  python experiments/reinforce_pendulum.py --seeds 3
  python experiments/reinforce_pendulum.py --baseline value --hidden 64,64 --gif
"""

from rl_jax.agents.reinforce import reinforce
from rl_jax.run import cli

if __name__ == "__main__":
    cli.main(reinforce, "rl_jax/InvertedPendulum-v5", __doc__, seeds=5, total_steps=4_800_000)
