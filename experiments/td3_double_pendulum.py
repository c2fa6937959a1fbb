"""TD3 on rl_jax/InvertedDoublePendulum-v5 (MuJoCo, gymnasium's v5), all seeds as one compiled
program.

Balance two poles on a cart: +10 per step alive minus distance and velocity penalties, episodes
end when the tip drops below 1 m or after 1,000 steps (a perfect policy scores about 9,350).
4 envs stepped together, one gradient update per env step, 256x256 networks and the TD3 paper's
settings otherwise; physics on MuJoCo C (the default CPU backend, bit-for-bit gymnasium's).

It prints its plan (envs, steps, memory, devices, estimated time) before it starts, then a
progress bar (env steps/s, updates/s, ETA, latest eval return over seeds). Ctrl-C or SIGTERM
finishes the current chunk, writes a checkpoint and prints the command that resumes the run.

examples:
  python experiments/td3_double_pendulum.py --seeds 5 --out runs/idp --gif
  python experiments/td3_double_pendulum.py --resume runs/idp --total-steps 200000
"""

from rl_jax.agents.td3 import td3
from rl_jax.run.script import Script

SCRIPT = Script(td3, "rl_jax/InvertedDoublePendulum-v5", seeds=5, total_steps=100_000)

if __name__ == "__main__":
    SCRIPT.main(__doc__)
