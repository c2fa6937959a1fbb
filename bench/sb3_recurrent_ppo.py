"""sb3-contrib's RecurrentPPO timed on CartPole-v1 with its velocities masked: the peer
``bench_recurrent_ppo_sb3`` sets beside our recurrent PPO. Runs in the peers' venv
(``bench/peers.py``); imports nothing of rl_jax.

    .venv-peers/bin/python bench/sb3_recurrent_ppo.py --steps 102400 --threads 1

The settings of our recurrent PPO's recipe for ``rl_jax/CartPoleNoVel-v1`` (rl-baselines3-zoo's
``ppo_lstm`` one), in sb3-contrib's terms: 8 envs (``DummyVecEnv``) x 32 steps per rollout, 20
epochs of one minibatch of all 256 steps, observations standardised by running statistics and
clipped to +-10 (``VecNormalize``, rewards left as they are), gamma 0.98, lambda 0.8, Adam at
1e-3 (eps 1e-5, SB3's for PPO) and the clip range 0.2, both falling linearly to 0 over 100,000 env
steps, advantages standardised per minibatch, no entropy bonus, gradients clipped to norm 0.5.

The network is ours: the observation straight into one 64-unit LSTM (``lstm_hidden_size=64``),
and a linear policy head and a linear value head on its output (``net_arch=[]``); actor and
critic share the LSTM (``shared_lstm=True, enable_critic_lstm=False``), orthogonal init. Our loss
is ``policy + 0.5 * 0.5 * mean squared value error``; sb3-contrib's has no 0.5 inside, so its
``vf_coef`` is 0.25. The env is gymnasium's CartPole-v1 observing ``(x, 0, theta, 0)``: the
velocities (entries 1 and 3) read 0, as RL Zoo's ``CartPoleNoVel-v1`` and ours.

Start-up (building the env and the model) is timed apart; then ``--warmup`` env steps of
``learn`` (torch's first calls), untimed; then ``learn`` goes on, timed, for ``--steps`` more env
steps (whole rollouts of 256). PyTorch runs on ``--threads`` threads (``torch.set_num_threads``);
the envs step in the main thread. Prints one JSON line: env steps, seconds, env steps/s,
start-up and warm-up seconds, threads, versions and the load.
"""

from __future__ import annotations

import argparse
import json
import os
import time

NUM_ENVS = 8
NUM_STEPS = 32
ROLLOUT = NUM_ENVS * NUM_STEPS  # env steps per rollout
NUM_EPOCHS = 20
BATCH_SIZE = 256  # one minibatch of the whole rollout
LSTM_SIZE = 64
LEARNING_RATE = 1e-3
CLIP_RANGE = 0.2
DECAY_STEPS = 100_000  # env steps over which the rate and the clip range fall to 0
GAMMA = 0.98
GAE_LAMBDA = 0.8
VF_COEF = 0.25  # ours: 0.5 x 0.5 mean squared error; sb3-contrib: vf_coef x mean squared error
MAX_GRAD_NORM = 0.5
VELOCITIES = (1, 3)  # CartPole's entries that read 0
WARMUP = 2 * ROLLOUT


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: env steps to time, warm-up steps, torch threads, seed."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--steps", type=int, default=10_240, help="env steps to time (learn())")
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
    set once the model exists)."""

    def __init__(self, start: float) -> None:
        self.start = start
        self.model: object = None

    def __call__(self, _progress_remaining: float) -> float:
        done = getattr(self.model, "num_timesteps", ROLLOUT) - ROLLOUT
        return self.start * min(1.0, max(0.0, 1.0 - done / DECAY_STEPS))


def make_env():
    """Gymnasium's CartPole-v1 observing ``(x, 0, theta, 0)``."""
    import gymnasium as gym
    import numpy as np

    class MaskVelocity(gym.ObservationWrapper):
        """Entries 0 and 2 kept, the velocities set to 0 (the space keeps its shape)."""

        def __init__(self, env: gym.Env) -> None:
            super().__init__(env)
            self.mask = np.ones(4, np.float32)
            self.mask[list(VELOCITIES)] = 0.0

        def observation(self, observation):
            """The observation with its velocities set to 0."""
            return observation * self.mask

    return MaskVelocity(gym.make("CartPole-v1"))


def build(seed: int):
    """The model of the module docstring, on fresh normalised envs."""
    from sb3_contrib import RecurrentPPO  # type: ignore[import-not-found]  # the peers' venv's
    from stable_baselines3.common.vec_env import (  # type: ignore[import-not-found]
        DummyVecEnv,
        VecNormalize,
    )

    env = DummyVecEnv([make_env] * NUM_ENVS)
    env = VecNormalize(env, norm_obs=True, norm_reward=False, clip_obs=10.0, gamma=GAMMA)
    rate, clip = Decay(LEARNING_RATE), Decay(CLIP_RANGE)
    model = RecurrentPPO(
        "MlpLstmPolicy",
        env,
        learning_rate=rate,
        n_steps=NUM_STEPS,
        batch_size=BATCH_SIZE,
        n_epochs=NUM_EPOCHS,
        gamma=GAMMA,
        gae_lambda=GAE_LAMBDA,
        clip_range=clip,
        clip_range_vf=None,
        normalize_advantage=True,
        ent_coef=0.0,
        vf_coef=VF_COEF,
        max_grad_norm=MAX_GRAD_NORM,
        policy_kwargs={
            "net_arch": [],
            "lstm_hidden_size": LSTM_SIZE,
            "n_lstm_layers": 1,
            "shared_lstm": True,
            "enable_critic_lstm": False,
            "ortho_init": True,
        },
        seed=seed,
        device="cpu",
        verbose=0,
    )
    rate.model = clip.model = model
    return model


def main(argv: list[str] | None = None) -> None:
    """Build, warm up, time ``learn``, print the JSON line."""
    args = parse_args(argv)
    import gymnasium
    import sb3_contrib  # the peers' venv's, as the two below
    import stable_baselines3  # type: ignore[import-not-found]
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
        "peer": "sb3-contrib RecurrentPPO",
        "env_steps": steps,
        "seconds": round(seconds, 3),
        "env_steps_per_s": round(steps / seconds, 1),
        "startup_s": round(startup, 3),
        "warmup_steps": warmup_steps,
        "warmup_s": round(warmup, 3),
        "threads": torch.get_num_threads(),
        "sb3_contrib": sb3_contrib.__version__,
        "stable_baselines3": stable_baselines3.__version__,
        "torch": torch.__version__,
        "gymnasium": gymnasium.__version__,
        "load": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
