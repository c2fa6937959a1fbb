"""gymnasium's own CartPole frames as the pixel env's observations: its pygame ``rgb_array``
rendering, ITU-R 601 grayscale and exact area-averaging in numpy (not our JAX renderer), for the
frame-parity tests and for driving a trained pixel policy on gymnasium's CartPole-v1."""

import os

import numpy as np


def area_weights(n_out: int, n_in: int) -> np.ndarray:
    """``[n_out, n_in]``: the share of each input pixel in each output pixel (exact area
    averaging, also for sizes that do not divide)."""
    edges = np.arange(n_out + 1) * (n_in / n_out)
    pixels = np.arange(n_in)[None, :]
    overlap = np.minimum(edges[1:, None], pixels + 1) - np.maximum(edges[:-1, None], pixels)
    return np.clip(overlap, 0.0, None) / (n_in / n_out)


def preprocess(rgb: np.ndarray, size: int) -> np.ndarray:
    """``[size, size]`` float64 gray levels of an RGB frame."""
    gray = rgb.astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    return area_weights(size, rgb.shape[0]) @ gray @ area_weights(size, rgb.shape[1]).T


def play_cartpole(policy, episodes: int, size: int = 84, stack: int = 4, seed: int = 0) -> list:
    """Returns of ``policy`` (uint8 ``[size, size, stack]`` -> action) on gymnasium's
    ``CartPole-v1``, seeing the last ``stack`` preprocessed frames of its own rendering (a reset
    repeats its first frame, as ``rl_jax/CartPolePixels-v1`` does)."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # no display: pygame draws off screen
    import gymnasium

    env = gymnasium.make("CartPole-v1", render_mode="rgb_array")
    returns = []
    for episode in range(episodes):
        env.reset(seed=seed + episode)

        def frame():
            return np.round(preprocess(env.render(), size)).astype(np.uint8)[..., None]

        frames, total, done = np.repeat(frame(), stack, axis=-1), 0.0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(int(policy(frames)))
            total, done = total + float(reward), terminated or truncated
            frames = np.concatenate([frames[..., 1:], frame()], axis=-1)
        returns.append(total)
    env.close()
    return returns
