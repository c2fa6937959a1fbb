"""DQN from pixels on rl_jax/CartPolePixels-v1, all seeds as one compiled program.

The env is CartPole-v1 step for step, but the agent sees only the last 4 grayscale frames
(84x84 uint8 by default, --frame-size / --frame-stack), drawn in JAX inside the compiled step as
gymnasium would render them. The Q-network is a conv torso (--conv-layers: features, kernel,
stride per layer; default the 2013 DQN paper's 16 8x8/4, 32 4x4/2) then --hidden ReLU layers;
pixels are scaled to [0, 1] inside the network. The replay keeps each frame once per step and
rebuilds the stacks when it samples (about 14 KB per transition at 84x84 instead of 56 KB for
two uint8 stacks); the plan counts it before anything is allocated. The options of
experiments/dqn_cartpole.py apply: --double, --dueling, --n-step 3, --prioritized, and DrQ's random
shifts of the sampled frames (--augment-shift 4: up to 4 pixels each way, in the loss only; on
CartPole it stopped learning). The recipe
(in rl_jax.agents.dqn) uses Double DQN with 3-step returns, a target update every 500
updates, LayerNorm in the 256-unit layer (--norm none: without), rate 5e-4 falling linearly to 0
over the 200k steps (--lr-decay-steps 0: constant) and one batch-32 update per 4 env steps, and
its torso sees only the 36 rows of the frame that CartPole ever draws on (--no-crop-drawn-rows:
all 84). Its default budget is 3 seeds x 200k env steps. Check a run's policies on fresh episodes
with python -m rl_jax.run.evaluate RUN_DIR --latest.

examples:
  python experiments/dqn_cartpole_pixels.py --seeds 3
  python experiments/dqn_cartpole_pixels.py --frame-size 64 --double --dueling --gif
  python experiments/dqn_cartpole_pixels.py --resume runs/<dir> --total-steps 200000
"""

from rl_jax.agents.dqn import dqn
from rl_jax.run.script import Script

SCRIPT = Script(dqn, "rl_jax/CartPolePixels-v1", seeds=3, total_steps=200_000)

if __name__ == "__main__":
    SCRIPT.main(__doc__)
