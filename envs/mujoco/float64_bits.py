"""float64 values through JAX without x64: the C backend's state travels as the raw bits of its
float64 numbers, two uint32 words each (little-endian, so a host-side ``.view(np.float64)``
recovers them). Bits are copied, never rounded (see ``envs.mujoco.mujoco_backend``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

Array = jax.Array


def float32_to_float64_bits(x: Array) -> Array:
    """``[...]`` float32 -> ``[..., 2]`` uint32, the (low, high) words of the exact float64 value.

    Widening float32 to float64 is exact; this does it with integer ops so that it runs inside a
    jitted program without x64. Handles zeros, subnormals, infinities and NaN like numpy's
    ``astype(np.float64)``.
    """
    bits = jax.lax.bitcast_convert_type(jnp.asarray(x, jnp.float32), jnp.uint32)
    sign = bits & jnp.uint32(0x80000000)
    exponent = (bits >> 23) & jnp.uint32(0xFF)
    mantissa = bits & jnp.uint32(0x7FFFFF)
    is_subnormal = (exponent == 0) & (mantissa != 0)
    # A float32 subnormal is a normal float64: shift its leading 1 up to the implicit-bit position.
    shift = jax.lax.clz(mantissa) - jnp.uint32(8)
    normalized = (mantissa << shift) & jnp.uint32(0x7FFFFF)
    exponent64 = jnp.where(exponent == 0xFF, jnp.uint32(0x7FF), exponent + jnp.uint32(1023 - 127))
    exponent64 = jnp.where(exponent == 0, jnp.uint32(0), exponent64)
    exponent64 = jnp.where(is_subnormal, jnp.uint32(1023 - 126) - shift, exponent64)
    mantissa = jnp.where(is_subnormal, normalized, mantissa)
    high = sign | (exponent64 << 20) | (mantissa >> 3)
    low = (mantissa & jnp.uint32(0x7)) << 29
    return jnp.stack([low, high], axis=-1)


def float64_bits_to_float32(bits: Array) -> Array:
    """uint32 ``[..., 2 n]`` (low, high words) -> float32 ``[..., n]``, rounded to nearest even.

    The float32 view JAX code reads (observations at reset); the exact values stay in the bits.
    Magnitudes below float32's normal range (2**-126) become signed zero, as XLA:CPU's float32
    arithmetic flushes them anyway.
    """
    words = bits.reshape(*bits.shape[:-1], -1, 2)
    low, high = words[..., 0], words[..., 1]
    sign = high & jnp.uint32(0x80000000)
    exponent = ((high >> 20) & jnp.uint32(0x7FF)).astype(jnp.int32)
    mantissa_high = high & jnp.uint32(0xFFFFF)
    # 23 kept mantissa bits: 20 from the high word and the top 3 of the low word.
    mantissa = (mantissa_high << 3) | (low >> 29)
    remainder = low & jnp.uint32(0x1FFFFFFF)
    half = jnp.uint32(0x10000000)
    round_up = (remainder > half) | ((remainder == half) & ((mantissa & 1) == 1))
    exponent32 = exponent - (1023 - 127)
    # Adding the rounding bit may carry into the exponent (and up to infinity): that is correct.
    magnitude = (jnp.clip(exponent32, 0, 255).astype(jnp.uint32) << 23) + mantissa
    magnitude = magnitude + round_up.astype(jnp.uint32)
    value = jax.lax.bitcast_convert_type(sign | magnitude, jnp.float32)
    infinity = jax.lax.bitcast_convert_type(sign | jnp.uint32(0x7F800000), jnp.float32)
    zero = jax.lax.bitcast_convert_type(sign, jnp.float32)
    is_nan = (exponent == 0x7FF) & ((mantissa_high != 0) | (low != 0))
    value = jnp.where(exponent32 >= 255, infinity, value)
    value = jnp.where(exponent32 <= 0, zero, value)
    return jnp.where(is_nan, jnp.float32(jnp.nan), value)


def float64_to_bits(x: np.ndarray) -> np.ndarray:
    """Host side: float64 ``[..., n]`` -> uint32 ``[..., 2 * n]`` (exact, little-endian words)."""
    x = np.ascontiguousarray(np.asarray(x, np.float64))
    return x.view(np.uint32).reshape(*x.shape[:-1], 2 * x.shape[-1])


def bits_to_float64(bits: np.ndarray) -> np.ndarray:
    """Host side: uint32 ``[..., 2 * n]`` -> float64 ``[..., n]``."""
    return np.ascontiguousarray(np.asarray(bits, np.uint32)).view(np.float64)
