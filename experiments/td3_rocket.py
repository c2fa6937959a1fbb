"""TD3 on rl_jax/Rocket-v0 (the 1-D rocket: bring a point mass to rest at the origin), all
seeds as one compiled program.

The rocket is inertial with a small time step, so independent exploration noise averages out
before it moves anything: exploration here is temporally correlated (AR(1) noise with
correlation 0.98 and std 0.5, the discrete Ornstein-Uhlenbeck process of the original DDPG), and
gamma is 0.995 (at 0.99 creeping towards the origin scores as well as arriving). 4 envs stepped
together, one gradient update per env step, 64x64 networks, otherwise the TD3 paper's settings
(td3's recipe for the env in rl_jax/agents/td3.py, with the measurements behind it).
Known shortfall: from (1, 0) the learned policies do not yet all settle inside |x|, |v| < 0.05
(tests/agents/test_td3_slow.py).
Episodes end after 500 steps, on leaving |x|, |v| <= 2 (-500) or on reaching the goal (+500).

It prints its plan (envs, steps, memory, devices, estimated time) before it starts, then a
progress bar (env steps/s, updates/s, ETA, latest eval return over seeds). Ctrl-C or SIGTERM
finishes the current chunk, writes a checkpoint and prints the command that resumes the run.

examples:
  python experiments/td3_rocket.py --seeds 5 --out runs/rocket --gif
  python experiments/td3_rocket.py --exploration-correlation 0 --out runs/rocket_white
"""

from rl_jax.agents.td3 import td3
from rl_jax.run.script import Script

SCRIPT = Script(td3, "rl_jax/Rocket-v0", seeds=5, total_steps=50_000)

if __name__ == "__main__":
    SCRIPT.main(__doc__)
