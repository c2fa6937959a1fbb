"""TD3 on rl_jax/Rocket-v0 (the 1-D rocket: bring a point mass to rest at the origin), all
seeds as one compiled program.

The rocket is inertial with a small time step, so independent exploration noise averages out
before it moves anything: exploration here is temporally correlated (AR(1) noise with
correlation 0.9, the discrete Ornstein-Uhlenbeck process of the original DDPG). 4 envs stepped
together, one gradient update per env step, 64x64 networks, otherwise the TD3 paper's settings.
Episodes end after 500 steps, on leaving |x|, |v| <= 2 (-500) or on reaching the goal (+500).

It prints its plan (envs, steps, memory, devices, estimated time) before it starts, then a
progress bar (env steps/s, updates/s, ETA, latest eval return over seeds). Ctrl-C or SIGTERM
finishes the current chunk, writes a checkpoint and prints the command that resumes the run.

examples:
  python experiments/td3_rocket.py --seeds 5 --out runs/rocket --gif
  python experiments/td3_rocket.py --exploration-correlation 0 --out runs/rocket_white
"""

from rl_jax import cli
from rl_jax.td3 import td3

ENV_ID = "rl_jax/Rocket-v0"
SEEDS = 5
TOTAL_STEPS = 50_000  # env steps per seed
CONFIG_OVERRIDES: dict = {
    "num_envs": 4,
    "updates_per_iteration": 4,  # one update per env step, as in the paper
    "iterations_per_chunk": 625,  # 2,500 env steps between evaluations
    "learning_starts": 2_000,
    "actor_hidden": (64, 64),
    "critic_hidden": (64, 64),
}
HPARAM_OVERRIDES: dict = {"exploration_correlation": 0.9}
# None: no throughput measured for these defaults yet; the time is estimated after the first
# training chunk.
THROUGHPUT = None

if __name__ == "__main__":
    cli.main(
        td3,
        ENV_ID,
        __doc__,
        seeds=SEEDS,
        total_steps=TOTAL_STEPS,
        config=CONFIG_OVERRIDES,
        hparams=HPARAM_OVERRIDES,
        throughput=THROUGHPUT,
    )
