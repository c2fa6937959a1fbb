"""Convolutions for image observations: the layer list ``(features, kernel, stride, ...)`` and its
checks, ``MatmulConv`` (a convolution as one matrix product over space-to-depth patches, with
``nn.Conv``'s parameters) and ``ConvTorso``, the torso that ``networks.QNetwork`` puts before its
dense layers; and the initialisers the two modules share.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
from jax.nn.initializers import Initializer
from jax.typing import DTypeLike

INITS = ("fan_in_uniform", "orthogonal")
LAYOUTS = ("auto", "patches", "products")  # MatmulConv.layout


def uniform_init(bound: float) -> Callable[..., jax.Array]:
    """Weights or biases ~ U(-bound, bound)."""

    def init(key: jax.Array, shape: Sequence[int], dtype: DTypeLike = jnp.float32) -> jax.Array:
        return jax.random.uniform(key, shape, dtype, -bound, bound)

    return init


def conv_layer_specs(layers: Sequence[int]) -> list[tuple[int, int, int]]:
    """``(features, kernel, stride)`` per conv layer from the flat tuple a config holds (a flat
    tuple of ints is one command-line flag: ``--conv-layers 32,8,4,64,4,2``)."""
    if len(layers) % 3 or any(int(value) < 1 for value in layers):
        raise ValueError(
            "conv layers are (features, kernel, stride) triples of integers >= 1, got "
            + ",".join(str(value) for value in layers)
        )
    return [tuple(int(v) for v in layers[i : i + 3]) for i in range(0, len(layers), 3)]


def conv_output_sizes(layers: Sequence[int], size: int) -> list[int]:
    """Side of the feature map after each conv layer (VALID padding) on a ``size`` square."""
    sizes = []
    for _, kernel, stride in conv_layer_specs(layers):
        size = (size - kernel) // stride + 1 if size >= kernel else 0
        sizes.append(size)
    return sizes


def check_conv_layers(layers: Sequence[int], size: int) -> None:
    """``ValueError`` naming the first layer whose kernel no longer fits on ``size`` frames,
    so a frame size too small for the conv stack is one line before anything is traced."""
    side = size
    for index, ((_, kernel, _), after) in enumerate(
        zip(conv_layer_specs(layers), conv_output_sizes(layers, size), strict=True)
    ):
        if after < 1:
            raise ValueError(
                f"frames of {size}x{size} are too small for the conv layers: layer {index + 1} "
                f"has a {kernel}x{kernel} kernel but sees {side}x{side} pixels; use larger "
                "frames or smaller kernels/strides"
            )
        side = after


def covering_rows(layers: Sequence[int], first: int, stop: int, size: int) -> tuple[int, int]:
    """The rows ``(first, stop)`` of a ``size``-row image to give the conv stack so that it sees
    the band ``[first, stop)`` whole: the band grown (centred, inside the image) to the least
    height every layer reads to its last row (VALID windows drop rows past the last full one).
    The whole image when no height fits."""
    first, stop = max(0, int(first)), min(size, int(stop))
    for height in range(max(stop - first, 1), size + 1):
        side, exact = height, True
        for _, kernel, stride in conv_layer_specs(layers):
            exact = exact and side >= kernel and (side - kernel) % stride == 0
            side = (side - kernel) // stride + 1
        if exact:
            start = min(max(0, first - (height - (stop - first)) // 2), size - height)
            return start, start + height
    return 0, size


def _conv_inits(initializer: str, fan_in: int) -> tuple[Initializer, Initializer]:
    """Kernel and bias initializers of a conv layer, as ``dense``'s (PyTorch's ``nn.Conv2d``
    default bound 1/sqrt(fan_in) for ``fan_in_uniform``; orthogonal with the ReLU gain
    otherwise)."""
    if initializer == "fan_in_uniform":
        return uniform_init(1.0 / fan_in**0.5), uniform_init(1.0 / fan_in**0.5)
    if initializer == "orthogonal":
        return nn.initializers.orthogonal(2.0**0.5), nn.initializers.zeros
    raise ValueError(f"unknown initializer {initializer!r}; choose one of {INITS}")


def uses_patches(out: tuple[int, int], blocks: tuple[int, int], depth: int, features: int) -> bool:
    """Whether ``MatmulConv`` multiplies concatenated patches (``out`` positions x taps x
    ``depth``) rather than summing per-tap products (``blocks`` x taps x ``features``): the
    layout that writes fewer floats."""
    return out[0] * out[1] * depth < blocks[0] * blocks[1] * features


class MatmulConv(nn.Module):
    """A VALID, square-strided 2-D convolution computed with one matmul, with ``nn.Conv``'s
    parameters (``kernel`` [k, k, C, F], ``bias`` [F]) and results (to float rounding).

    Why not ``nn.Conv``: on XLA's CPU backend a convolution's gradient inside a loop body (the
    training chunk's ``scan``) runs several times slower than the same convolution outside one
    (jax-ml/jax#12868), and vmapped over seeds each conv with per-seed weights becomes one slow
    grouped conv. Matmuls have neither problem.

    How: the input is cut to the rows and columns the conv reads and rearranged space-to-depth by
    the stride (``[bh, bw, s*s*C]`` blocks of ``s x s`` pixels), so a ``k x k`` kernel with
    stride ``s`` becomes ``m x m`` taps of stride 1 over blocks (``m = ceil(k / s)``; the kernel
    is zero-padded to ``m*s`` when ``s`` does not divide ``k``). One matmul gives every block's
    product with all ``m*m`` taps' weights at once (``[bh, bw, m, m, F]``), and the output is the
    sum of the ``m*m`` shifted tap slices. Where the input's blocks are deeper than the layer's
    features (Nature DQN's strided layers on frames), summing small outputs instead of
    concatenating ``m*m`` shifted copies of the input into patches moves less memory, and so
    takes less time (BENCHMARKS.md, "Pixel DQN"). Where they are shallower (MinAtar's 3x3 stride-1
    layer: 4-10 channels into 16 features), the products would be ``m*m`` times the output, and
    the layer concatenates the patches instead and multiplies them once (``uses_patches``;
    BENCHMARKS.md, "MinAtar's conv layer", has the timings of both).

    ``layout``: ``"auto"`` picks by that rule; ``"patches"`` or ``"products"`` forces one (the
    parameters and results are the same, only the time differs; tests and benchmarks compare
    them)."""

    features: int
    kernel: int
    stride: int
    initializer: str = "fan_in_uniform"
    dtype: DTypeLike = jnp.float32
    layout: str = "auto"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        if self.layout not in LAYOUTS:
            raise ValueError(f"unknown MatmulConv layout {self.layout!r}; choose one of {LAYOUTS}")
        k, s, channels, features = self.kernel, self.stride, x.shape[-1], self.features
        kernel_init, bias_init = _conv_inits(self.initializer, k * k * channels)
        kernel = self.param("kernel", kernel_init, (k, k, channels, features), jnp.float32)
        bias = self.param("bias", bias_init, (features,), jnp.float32)
        out = (x.shape[-3] - k) // s + 1, (x.shape[-2] - k) // s + 1
        taps = -(-k // s)
        blocks = out[0] + taps - 1, out[1] + taps - 1
        # Exactly the rows and columns the conv reads (zero rows for a zero-padded kernel).
        x = x[..., : blocks[0] * s, : blocks[1] * s, :]
        pad = [(0, 0)] * (x.ndim - 3)
        pad += [(0, blocks[0] * s - x.shape[-3]), (0, blocks[1] * s - x.shape[-2]), (0, 0)]
        x = jnp.pad(x, pad)
        lead = x.shape[:-3]
        x = x.reshape(*lead, blocks[0], s, blocks[1], s, channels)
        x = jnp.moveaxis(x, -4, -3).reshape(*lead, blocks[0], blocks[1], s * s * channels)
        size = taps * s
        kernel = jnp.pad(kernel, [(0, size - k), (0, size - k), (0, 0), (0, 0)])
        kernel = kernel.reshape(taps, s, taps, s, channels, features)
        multiply_patches = self.layout == "patches" or (
            self.layout == "auto" and uses_patches(out, blocks, s * s * channels, features)
        )
        if multiply_patches:
            # [(tap row, tap col), block rows, block cols, (row, col, C)] patches, one matmul
            patches = jnp.concatenate(
                [
                    x[..., u : u + out[0], v : v + out[1], :]
                    for u in range(taps)
                    for v in range(taps)
                ],
                axis=-1,
            )
            kernel = kernel.transpose(0, 2, 1, 3, 4, 5).reshape(-1, features)
            y = patches.astype(self.dtype) @ kernel.astype(self.dtype)
        else:
            y = self._summed_products(x, kernel, out, blocks)
        return y + jnp.reshape(bias.astype(self.dtype), (1,) * (y.ndim - 1) + (-1,))

    def _summed_products(
        self, x: jax.Array, kernel: jax.Array, out: tuple[int, int], blocks: tuple[int, int]
    ) -> jax.Array:
        """The conv as every block's product with all the taps' weights, then the sum of the
        taps' shifted slices (``x``: space-to-depth blocks; ``kernel``: [m, s, m, s, C, F])."""
        taps, s, _, _, channels, features = kernel.shape
        lead = x.shape[:-3]
        # [tap row, row in block, tap col, col in block, C, F] -> [(row, col, C), (taps, F)]
        kernel = kernel.transpose(1, 3, 4, 0, 2, 5).reshape(s * s * channels, -1)
        products = x.astype(self.dtype) @ kernel.astype(self.dtype)
        products = products.reshape(*lead, blocks[0], blocks[1], taps, taps, features)
        slices = [
            products[..., u : u + out[0], v : v + out[1], u, v, :]
            for u in range(taps)
            for v in range(taps)
        ]
        return functools.reduce(jnp.add, slices)


class ConvTorso(nn.Module):
    """Image features: ``[..., H, W, C]`` pixels in [0, ``high``] (uint8 frames: 255) ->
    ``[..., F]``.

    The network scales pixels to [0, 1] itself, so observations stay uint8 in the env, the
    replay buffer and the train state (a quarter of float32's memory). ReLU conv layers with
    VALID padding (``layers``: flat ``(features, kernel, stride)`` triples; Nature DQN's are
    ``(32, 8, 4, 64, 4, 2, 64, 3, 1)``), then the feature map is flattened. The layers are
    ``MatmulConv`` (``nn.Conv``'s parameters under ``nn.Conv``'s names, ``Conv_0``, ...)."""

    layers: tuple[int, ...]
    initializer: str = "fan_in_uniform"
    dtype: DTypeLike = jnp.float32
    rows: tuple[int, ...] = ()  # (first, stop): the only rows the layers see; () all of them
    # the observations' largest value, which the torso scales to 1: 255 for uint8 frames, 1 for
    # MinAtar's grids of 0/1
    high: float = 255.0

    @nn.compact
    def __call__(self, pixels: jax.Array) -> jax.Array:
        if self.rows:
            pixels = pixels[..., self.rows[0] : self.rows[1], :, :]
        check_conv_layers(self.layers, min(pixels.shape[-3], pixels.shape[-2]))
        x = pixels.astype(self.dtype) / self.high
        for index, (features, kernel, stride) in enumerate(conv_layer_specs(self.layers)):
            layer = MatmulConv(
                features, kernel, stride, self.initializer, self.dtype, name=f"Conv_{index}"
            )
            x = nn.relu(layer(x))
        return x.reshape(x.shape[:-3] + (-1,))
