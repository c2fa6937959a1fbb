"""Train any algorithm on any env: --algo and --env choose them; every other flag is as in the
other scripts (--help with --algo and --env lists the algorithm's flags and its defaults there).

  python experiments/train.py --algo td3 --env rl_jax/Pendulum-v1 --seeds 5
  python experiments/train.py --algo td3 --env rl_jax/Hopper-v5 --recipe paper-2018 --seeds 5
  python experiments/train.py --algo td3 --env gymnasium:Pendulum-v1 --seeds 5
  python experiments/train.py --algo td3 --env examples.hover_rocket:examples/HoverRocket-v0
  python experiments/train.py --resume runs/HoverRocket-v0__td3__...   # the run knows the rest

--env takes a registered id; gymnasium:ID, any env gymnasium.make knows, stepped on the host
through rl_jax.envs.from_gymnasium (slower than our JAX envs; a resume cuts the episodes that were
in flight, since gymnasium's env state is not in the checkpoint); or MODULE:ID, which imports
MODULE (your file, searched on the Python path and in the current directory) so that its
rl_jax.envs.register(ID, ...) runs first. The whole string is recorded as the run's env, so
--resume imports the module again. Algorithms without a recipe for an env start from their own
defaults (the TD3 paper's for td3: 25,000 random steps first), so small budgets need flags such
as --learning-starts. --recipe NAME puts one of the algorithm's whole named recipes on top of the
env's (td3 and ddpg: paper, the TD3 paper's loop, 256 x 256 networks and rates; td7; td7-cpu).
"""

from rl_jax.run import cli

if __name__ == "__main__":
    cli.main(None, None, __doc__, seeds=1, total_steps=100_000)
