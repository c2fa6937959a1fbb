"""TD3 on rl_jax/Pendulum-v1 (gymnasium's classic swing-up), all seeds as one compiled program.

4 envs stepped together, one gradient update per env step, 64x64 networks (td3's recipe for the
env), otherwise the TD3 paper's settings. A policy that swings up and balances scores about -150 per
200-step episode; a random one about -1,200.

It prints its plan (envs, steps, memory, devices, estimated time) before it starts, then a
progress bar (env steps/s, updates/s, ETA, latest eval return over seeds). Ctrl-C or SIGTERM
finishes the current chunk, writes a checkpoint and prints the command that resumes the run.

examples:
  python experiments/td3_pendulum.py --seeds 5 --out runs/pendulum --gif
  python experiments/td3_pendulum.py --resume runs/pendulum --total-steps 40000
  python experiments/td3_pendulum.py --grid actor_lr=1e-4,1e-3 --seeds 3
"""

from rl_jax.agents.td3 import td3
from rl_jax.run.script import Script

SCRIPT = Script(td3, "rl_jax/Pendulum-v1", seeds=5, total_steps=30_000)

if __name__ == "__main__":
    SCRIPT.main(__doc__)
