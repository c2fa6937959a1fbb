"""Stable-Baselines3's PPO timed on the numpy MinAtar Breakout (the ``minatar`` package): the peer
``bench_ppo_minatar_sb3`` sets beside our PPO on ``rl_jax/Breakout-MinAtar``. Runs in the peers'
venv (``bench/peers.py``); imports nothing of rl_jax.

    .venv-peers/bin/python bench/sb3_ppo_minatar.py --steps 16384 --threads 1

The settings of our PPO's MinAtar recipe (gymnax-blines' PPO), in SB3's terms: 64 envs
(``DummyVecEnv``) x 128 steps per rollout, 4 epochs of 8 minibatches of 1,024, an actor MLP and
a critic MLP of 2 x 256 ReLU units each on the flattened grid (``net_arch=dict(pi=[256, 256],
vf=[256, 256])``), orthogonal init, observations as they are (no ``VecNormalize``: the grid is
0/1 already), Adam at 1e-3 (eps 1e-5, SB3's for PPO) falling linearly to 0 over 10M env steps,
gamma 0.999, lambda 0.95, the ratio and the value clipped at 0.2, advantages standardised per
minibatch, entropy bonus 0.01, gradients clipped to norm 0.5. Our loss is ``policy + 0.5 * 0.5 *
mean squared value error``; SB3's has no 0.5 inside, so its ``vf_coef`` is 0.25.

The env (``Breakout`` below, our own gymnasium wrapper of ``minatar.Environment``) is as gymnax's
and so ours: the 10 x 10 x 4 grid of 0/1 as float32 (SB3's ``MlpPolicy`` flattens it), the
game's minimal action set (3 actions), no sticky actions, episodes truncated at 1,000 steps
(SB3 bootstraps through the truncation, as ours).

Start-up (building the envs and the model) is timed apart; then ``--warmup`` env steps of
``learn`` (one rollout and its update: torch's first calls), untimed; then ``learn`` goes on,
timed, for ``--steps`` more env steps (whole rollouts of 8,192). PyTorch runs on ``--threads``
threads (``torch.set_num_threads``); the envs step in the main thread. Prints one JSON line: env
steps, seconds, env steps/s, start-up and warm-up seconds, threads, versions and the load.
"""

from __future__ import annotations

import argparse
import json
import os
import time

GAME = "breakout"  # minatar.Environment's name for Breakout
NUM_ENVS = 64
NUM_STEPS = 128
ROLLOUT = NUM_ENVS * NUM_STEPS  # env steps per rollout
NUM_EPOCHS = 4
NUM_MINIBATCHES = 8
BATCH_SIZE = ROLLOUT // NUM_MINIBATCHES  # SB3's batch_size: the steps of one minibatch
HIDDEN = (256, 256)  # the actor's and the critic's layers, each its own MLP
ACTIVATION = "relu"
LEARNING_RATE = 1e-3
DECAY_STEPS = 10_000_000  # env steps over which the rate falls to 0
GAMMA = 0.999
GAE_LAMBDA = 0.95
CLIP_RANGE = 0.2
CLIP_RANGE_VF = 0.2
ENT_COEF = 0.01
VF_COEF = 0.25  # ours: 0.5 x 0.5 mean squared error; SB3: vf_coef x mean squared error
MAX_GRAD_NORM = 0.5
MAX_EPISODE_STEPS = 1_000  # gymnax's max_steps_in_episode for Breakout
WARMUP = ROLLOUT


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: env steps to time, warm-up steps, torch threads, seed."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--steps", type=int, default=2 * ROLLOUT, help="env steps to time (learn())"
    )
    parser.add_argument("--warmup", type=int, default=WARMUP, help="env steps before timing")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    if args.steps < 1 or args.threads < 1 or args.warmup < 0:
        parser.error("--steps and --threads must be >= 1, --warmup >= 0")
    return args


class Decay:
    """``start`` falling linearly to 0 over ``DECAY_STEPS`` env steps counted before the rollout
    just collected, as our ``linearly_decayed`` (SB3 calls it after each rollout; ``model`` is
    set once the model exists). SB3's own schedules run over one ``learn`` call's budget, which
    here is not the recipe's 10M steps."""

    def __init__(self, start: float) -> None:
        self.start = start
        self.model: object = None

    def __call__(self, _progress_remaining: float) -> float:
        done = getattr(self.model, "num_timesteps", ROLLOUT) - ROLLOUT
        return self.start * min(1.0, max(0.0, 1.0 - done / DECAY_STEPS))


def make_env():
    """One numpy MinAtar Breakout as a gymnasium env (the module docstring's)."""
    import gymnasium as gym
    import numpy as np
    from minatar import Environment  # type: ignore[import-not-found]  # the peers' venv's

    class Breakout(gym.Env):
        """``minatar.Environment("breakout")`` without sticky actions: the grid as float32,
        the minimal action set, episodes truncated at ``MAX_EPISODE_STEPS``."""

        def __init__(self) -> None:
            self.game = Environment(GAME, sticky_action_prob=0.0)
            self.actions = list(self.game.minimal_action_set())
            shape = tuple(self.game.state_shape())
            self.observation_space = gym.spaces.Box(0.0, 1.0, shape, np.float32)
            self.action_space = gym.spaces.Discrete(len(self.actions))
            self.steps = 0

        def observation(self) -> np.ndarray:
            """The grid of 0/1, channels last, as float32."""
            return self.game.state().astype(np.float32)

        def reset(self, *, seed: int | None = None, options: dict | None = None):
            """A new episode; ``seed`` (SB3 gives each env its own) seeds the game."""
            super().reset(seed=seed)
            if seed is not None:
                self.game.seed(seed)
            self.game.reset()
            self.steps = 0
            return self.observation(), {}

        def step(self, action):
            """The game's step on the minimal action ``action`` picks."""
            reward, terminated = self.game.act(self.actions[int(action)])
            self.steps += 1
            truncated = not terminated and self.steps >= MAX_EPISODE_STEPS
            return self.observation(), float(reward), bool(terminated), truncated, {}

    return Breakout()


def build(seed: int):
    """The model of the module docstring, on fresh envs."""
    import torch  # type: ignore[import-not-found]  # the peers' venv's, as the two below
    from stable_baselines3 import PPO  # type: ignore[import-not-found]
    from stable_baselines3.common.vec_env import DummyVecEnv  # type: ignore[import-not-found]

    activation = {"relu": torch.nn.ReLU, "tanh": torch.nn.Tanh}[ACTIVATION]
    env = DummyVecEnv([make_env] * NUM_ENVS)
    rate = Decay(LEARNING_RATE)
    model = PPO(
        "MlpPolicy",
        env,
        learning_rate=rate,
        n_steps=NUM_STEPS,
        batch_size=BATCH_SIZE,
        n_epochs=NUM_EPOCHS,
        gamma=GAMMA,
        gae_lambda=GAE_LAMBDA,
        clip_range=CLIP_RANGE,
        clip_range_vf=CLIP_RANGE_VF,
        normalize_advantage=True,
        ent_coef=ENT_COEF,
        vf_coef=VF_COEF,
        max_grad_norm=MAX_GRAD_NORM,
        policy_kwargs={
            "net_arch": {"pi": list(HIDDEN), "vf": list(HIDDEN)},
            "activation_fn": activation,
            "ortho_init": True,
        },
        seed=seed,
        device="cpu",
        verbose=0,
    )
    rate.model = model
    return model


def main(argv: list[str] | None = None) -> None:
    """Build, warm up, time ``learn``, print the JSON line."""
    args = parse_args(argv)
    from importlib.metadata import version

    import gymnasium
    import stable_baselines3  # type: ignore[import-not-found]  # the peers' venv's
    import torch  # type: ignore[import-not-found]

    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    model = build(args.seed)
    startup = time.perf_counter() - start
    start = time.perf_counter()
    if args.warmup:
        model.learn(total_timesteps=args.warmup)
    warmup_steps = int(model.num_timesteps)
    warmup = time.perf_counter() - start
    start = time.perf_counter()
    model.learn(total_timesteps=args.steps, reset_num_timesteps=False)
    seconds = time.perf_counter() - start
    steps = int(model.num_timesteps) - warmup_steps
    result = {
        "peer": "sb3 PPO on numpy MinAtar",
        "env_steps": steps,
        "seconds": round(seconds, 3),
        "env_steps_per_s": round(steps / seconds, 1),
        "startup_s": round(startup, 3),
        "warmup_steps": warmup_steps,
        "warmup_s": round(warmup, 3),
        "threads": torch.get_num_threads(),
        "stable_baselines3": stable_baselines3.__version__,
        "torch": torch.__version__,
        "gymnasium": gymnasium.__version__,
        "minatar": version("minatar"),
        "load": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
