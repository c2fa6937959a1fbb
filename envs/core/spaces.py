"""Box and Discrete spaces: static shapes and bounds, jax sampling, gymnasium conversion."""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt

#: A box's dtype unless it names one.
_FLOAT32 = np.dtype(np.float32)


class Space:
    """Base of the action and observation spaces: a shape and dtype, sampling and membership."""

    shape: tuple[int, ...]
    dtype: np.dtype

    def sample(self, key: jax.Array) -> jax.Array:
        """A uniform random element of the space (inside JAX)."""
        raise NotImplementedError

    def contains(self, x: jax.Array) -> jax.Array:
        """Whether ``x`` has the space's shape and lies within its bounds, as a scalar bool
        array.
        """
        raise NotImplementedError

    def to_gymnasium(self):
        """The equivalent ``gymnasium.spaces`` object."""
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class Box(Space):
    """A box ``low <= x <= high``. ``low``/``high`` are numpy arrays of ``shape`` (static)."""

    low: np.ndarray
    high: np.ndarray
    shape: tuple[int, ...] = ()
    dtype: np.dtype = _FLOAT32

    # Written out rather than generated: the bounds may be scalars or any array-like (a jax
    # array too), broadcast to ``shape`` here, while the fields always hold numpy arrays.
    def __init__(
        self,
        low: npt.ArrayLike,
        high: npt.ArrayLike,
        shape: tuple[int, ...] = (),
        dtype: np.dtype = _FLOAT32,
    ) -> None:
        shape = tuple(shape) or np.broadcast(np.asarray(low), np.asarray(high)).shape
        low_array = np.broadcast_to(np.asarray(low, dtype), shape).copy()
        high_array = np.broadcast_to(np.asarray(high, dtype), shape).copy()
        if np.any(low_array > high_array):
            raise ValueError(f"Box low must be <= high, got {low_array} and {high_array}")
        object.__setattr__(self, "shape", shape)
        object.__setattr__(self, "low", low_array)
        object.__setattr__(self, "high", high_array)
        object.__setattr__(self, "dtype", dtype)

    @property
    def bounded(self) -> bool:
        """Whether every bound is finite (then ``sample`` is uniform over the box)."""
        return bool(np.all(np.isfinite(self.low)) and np.all(np.isfinite(self.high)))

    def sample(self, key: jax.Array) -> jax.Array:
        """Uniform on a bounded box; standard normal clipped to the box otherwise."""
        if self.bounded:
            return jax.random.uniform(
                key, self.shape, self.dtype, jnp.asarray(self.low), jnp.asarray(self.high)
            )
        x = jax.random.normal(key, self.shape, self.dtype)
        return jnp.clip(x, self.low, self.high)

    def contains(self, x: jax.Array) -> jax.Array:
        """Whether ``x`` has the box's shape and lies within ``[low, high]`` elementwise."""
        x = jnp.asarray(x)
        return jnp.logical_and(x.shape == self.shape, jnp.all((x >= self.low) & (x <= self.high)))

    def to_gymnasium(self):
        """The same box as a ``gymnasium.spaces.Box``."""
        return gymnasium.spaces.Box(self.low, self.high, self.shape, self.dtype)

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, Box)
            and self.shape == other.shape
            and self.dtype == other.dtype
            and np.array_equal(self.low, other.low)
            and np.array_equal(self.high, other.high)
        )

    def __hash__(self) -> int:
        return hash((self.shape, str(self.dtype), self.low.tobytes(), self.high.tobytes()))

    def __repr__(self) -> str:
        return f"Box({self.low.min()}, {self.high.max()}, {self.shape}, {self.dtype})"


@dataclass(frozen=True)
class Discrete(Space):
    """Integers ``0 .. n - 1``."""

    n: int
    shape: tuple[int, ...] = ()
    dtype: np.dtype = field(default_factory=lambda: np.dtype(np.int32))

    def __post_init__(self) -> None:
        if self.n < 1:
            raise ValueError(f"Discrete needs n >= 1, got {self.n}")

    def sample(self, key: jax.Array) -> jax.Array:
        """A uniform random action in ``0 .. n - 1``."""
        return jax.random.randint(key, self.shape, 0, self.n, self.dtype)

    def contains(self, x: jax.Array) -> jax.Array:
        """Whether ``x`` has the space's shape and every entry is in ``0 .. n - 1``."""
        x = jnp.asarray(x)
        return jnp.logical_and(x.shape == self.shape, jnp.all((x >= 0) & (x < self.n)))

    def to_gymnasium(self):
        """The same space as a ``gymnasium.spaces.Discrete``."""
        return gymnasium.spaces.Discrete(self.n)
