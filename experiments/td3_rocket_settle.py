"""TD3 on rl_jax/RocketSettle-v0: the 1-D rocket, rewarded for coming to rest at the origin and
staying there (the goal users of the rocket asked for), all seeds as one compiled program.

The faithful rl_jax/Rocket-v0 (experiments/td3_rocket.py) pays 2 - x^2 - v^2 per step near the
origin, so hovering 0.05 away costs almost nothing and its 1e-8 goal is never reached. This
variant keeps the dynamics and adds what "come to rest" means: each step inside |x|, |v| <= 0.01
earns +2 (the episode goes on), plus a sharp peak at the scale of that box; half of its resets
start near the goal, and it observes (x, v) with zoomed copies tanh(x / 0.03), tanh(v / 0.03)
(envs/classic/rocket.py). Same TD3 recipe as the faithful rocket: AR(1) exploration noise
(correlation 0.98, std 0.5), gamma 0.995, 64x64 networks, one update per env step; 200,000 env
steps per seed (RESULTS.md, "The rocket": how many seeds come to rest in the box from (1, 0)).

Compare the learned policy with the time-optimal bang-bang controller (at rest at t = 2.0 s from
(1, 0)) and an LQR law:

  python experiments/rocket_report.py runs/rocket_settle

examples:
  python experiments/td3_rocket_settle.py --seeds 5 --out runs/rocket_settle --gif
"""

import dataclasses

import td3_rocket

# The faithful rocket's script (budget, evaluation interval, the rocket's TD3 recipe) on the
# variant's reward.
SCRIPT = dataclasses.replace(
    td3_rocket.SCRIPT, env_id="rl_jax/RocketSettle-v0", total_steps=200_000
)

if __name__ == "__main__":
    SCRIPT.main(__doc__)
