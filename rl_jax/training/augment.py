"""Image augmentation for learning from frames: DrQ's random shifts.

DrQ (Kostrikov, Yarats and Fergus 2021; Yarats et al. 2021 for DQN on Atari) regularises a
value network on pixels by showing it each sampled observation moved by a few pixels: the image
is padded by repeating its edge pixels, then cropped back to its size at a random offset. All
channels of one image (the stacked frames of one observation) move together, so what changes
from frame to frame (a velocity) is kept; images of a batch move independently.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def random_shift(key: jax.Array, images: jax.Array, pad: int) -> jax.Array:
    """``images`` [B, H, W, C] each moved by up to ``pad`` pixels in each axis (edge pixels
    repeated into the space left), one uniform offset in ``-pad..pad`` per image and axis; the
    dtype is kept. ``pad = 0`` returns ``images`` as they are."""
    if pad == 0:
        return images
    if pad < 0:
        raise ValueError(f"pad must be >= 0, got {pad}")
    batch, height, width, channels = images.shape
    padded = jnp.pad(images, ((0, 0), (pad, pad), (pad, pad), (0, 0)), mode="edge")
    corners = jax.random.randint(key, (batch, 2), 0, 2 * pad + 1)

    def crop(image: jax.Array, corner: jax.Array) -> jax.Array:
        start = (corner[0], corner[1], 0)
        return jax.lax.dynamic_slice(image, start, (height, width, channels))

    return jax.vmap(crop)(padded, corners)
