"""Cart-pole seen as pixels (``rl_jax/CartPolePixels-v1``): ``rl_jax/CartPole-v1``'s dynamics,
observed as the last ``frame_stack`` grayscale frames, drawn in pure JAX.

The physics is ``envs.classic.cartpole.CartPole``'s own state and step (composed, not copied), so
the two envs stay identical step for step, including reward, termination and the 500-step limit.

Frames are drawn where they are used: inside the jitted, vmapped step, with no host round trip,
so thousands of envs render in one compiled call. Each output pixel is the average over a
``supersample x supersample`` grid of points inside the screen area it covers, and each point is
tested against the shapes of gymnasium's ``rgb_array`` frame (a 600x400 screen, the cart 50x30 on
a one-pixel track, the pole 10 wide from the axle, the axle a circle of radius 5), painted in
gymnasium's order. The frame so equals gymnasium's rendering, converted to grayscale (ITU-R 601
luma) and area-averaged down to ``frame_size x frame_size``, up to sampling error (checked by
tests/envs/test_cartpole_pixels.py). The screen is squeezed to a square, as Atari frames are.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax.envs.classic.cartpole import CartPole, CartPoleParams, CartPoleState
from rl_jax.envs.core.core import Array, Environment, EnvState, PRNGKey
from rl_jax.envs.core.spaces import Box, Discrete

# gymnasium's CartPole screen, in its own surface coordinates before its vertical flip: x right,
# y up from the bottom; the point (u, v) lies in surface pixel (floor(u), floor(v)).
SCREEN_WIDTH, SCREEN_HEIGHT = 600, 400
CART_HALF_WIDTH, CART_HALF_HEIGHT = 25.0, 15.0
POLE_HALF_WIDTH = 5.0  # the pole also reaches this far below the axle
CART_Y = 100.0  # the cart's centre line, which is also the track's row
AXLE_Y = CART_Y + 2 * CART_HALF_HEIGHT / 4.0  # gymnasium's axle offset: a quarter cart height
AXLE_RADIUS = 5.0
# pygame truncates vertices to whole pixels and fills every pixel whose corner lies inside the
# shape or on its boundary: on average the shape grown by half a pixel on every side.
FILL_MARGIN = 0.5


def _luma(rgb: tuple[int, int, int]) -> float:
    """ITU-R 601 luma, the usual RGB -> gray of image libraries (PIL's "L", OpenCV)."""
    return 0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]


WHITE, BLACK = 255.0, 0.0
POLE_GRAY = _luma((202, 152, 101))
AXLE_GRAY = _luma((129, 132, 203))


@struct.dataclass
class CartPolePixelsState(EnvState):
    """The cart-pole's physics plus the stack of its latest frames."""

    physics: CartPoleState  # the cart-pole itself, stepped by envs.classic.cartpole
    frames: Array  # [frame_size, frame_size, frame_stack] uint8, the newest frame last


def _sample_axis(count: int, supersample: int, extent: int) -> Array:
    """Screen coordinates of the sample points along one axis: ``[count * supersample]``."""
    points = count * supersample
    return (jnp.arange(points, dtype=jnp.float32) + 0.5) * (extent / points)


def _track_coverage(frame_size: int) -> Array:
    """``[frame_size]``: the part of each output row the one-pixel track covers, exactly (a
    one-pixel line falls between sample rows). The track is row ``CART_Y`` of the surface,
    screen rows [299, 300) after gymnasium's vertical flip."""
    row_height = SCREEN_HEIGHT / frame_size
    top = jnp.arange(frame_size, dtype=jnp.float32) * row_height
    track_top = SCREEN_HEIGHT - CART_Y - 1.0
    overlap = jnp.minimum(top + row_height, track_top + 1.0) - jnp.maximum(top, track_top)
    return jnp.clip(overlap, 0.0, None) / row_height


def draw_frame(
    x: Array, theta: Array, params: CartPoleParams, frame_size: int = 84, supersample: int = 4
) -> Array:
    """``[frame_size, frame_size]`` uint8: gymnasium's CartPole frame for cart position ``x``
    and pole angle ``theta``, grayscale and area-averaged (see the module docstring). Pure JAX:
    jit, vmap and grad-free; no loop over pixels."""
    scale = SCREEN_WIDTH / (2.0 * params.x_threshold)
    cart_x = x * scale + SCREEN_WIDTH / 2.0
    pole_top = scale * 2.0 * params.length - POLE_HALF_WIDTH
    first, stop = _rows_to_draw(frame_size, params)
    u = _sample_axis(frame_size, supersample, SCREEN_WIDTH)[None, :]
    v = _sample_axis(frame_size, supersample, SCREEN_HEIGHT)[
        first * supersample : stop * supersample
    ]
    v = SCREEN_HEIGHT - v[:, None]
    half_width, half_height = CART_HALF_WIDTH + FILL_MARGIN, CART_HALF_HEIGHT + FILL_MARGIN
    cart = (jnp.abs(u - cart_x) <= half_width) & (jnp.abs(v - CART_Y) <= half_height)
    # The pole in its own frame: ``across`` the pole and ``along`` it from the axle.
    du, dv = u - cart_x, v - AXLE_Y
    sin, cos = jnp.sin(theta), jnp.cos(theta)
    across, along = du * cos - dv * sin, du * sin + dv * cos
    pole = (
        (jnp.abs(across) <= POLE_HALF_WIDTH + FILL_MARGIN)
        & (along >= -POLE_HALF_WIDTH - FILL_MARGIN)
        & (along <= pole_top + FILL_MARGIN)
    )
    # gymnasium centres the axle circle on whole pixels (``int(cartx)``, ``int(carty + off)``).
    axle_dx, axle_dy = u - jnp.floor(cart_x), v - jnp.floor(AXLE_Y)
    axle = axle_dx**2 + axle_dy**2 <= (AXLE_RADIUS + FILL_MARGIN) ** 2
    gray = jnp.where(axle, AXLE_GRAY, jnp.where(pole, POLE_GRAY, jnp.where(cart, BLACK, WHITE)))
    area = gray.reshape(stop - first, supersample, frame_size, supersample).mean(axis=(1, 3))
    track = _track_coverage(frame_size)[first:stop]
    area = area * (1.0 - track)[:, None]  # the track is drawn last, black
    frame = jnp.round(area).astype(jnp.uint8)
    return jnp.pad(frame, ((first, frame_size - stop), (0, 0)), constant_values=255)


def _rows_to_draw(frame_size: int, params: CartPoleParams) -> tuple[int, int]:
    """The rows any state can draw on (``drawn_rows`` at any angle) when ``params`` are known
    while tracing, as the env's own defaults are; all rows when they are traced values. The
    other rows are white whatever the state, so they are not computed: 48 of 84 rows are."""
    try:
        return drawn_rows(frame_size, params, upright=False)
    except (jax.errors.ConcretizationTypeError, TypeError):
        return 0, frame_size


def drawn_rows(frame_size: int, params: CartPoleParams, upright: bool = True) -> tuple[int, int]:
    """``(first, stop)``: the rows of a ``frame_size``-row frame that the cart-pole can draw on;
    every other row is white in every frame. ``upright``: while the pole is at most 90 degrees
    from upright (an episode terminates at 12); otherwise at any angle. From the geometry above,
    at ``params``' scale and pole length (Python or numpy numbers, not traced values)."""
    scale = SCREEN_WIDTH / (2.0 * float(params.x_threshold))
    along = scale * 2.0 * float(params.length) - POLE_HALF_WIDTH + FILL_MARGIN
    reach = float(np.hypot(along, POLE_HALF_WIDTH + FILL_MARGIN))  # the pole's farthest corner
    top = AXLE_Y + reach
    bottom = CART_Y - CART_HALF_HEIGHT - FILL_MARGIN  # an upright pole stays above the cart's base
    if not upright:
        bottom = min(bottom, AXLE_Y - reach)
    rows_per_pixel = frame_size / SCREEN_HEIGHT
    first = int(np.floor((SCREEN_HEIGHT - top) * rows_per_pixel))
    stop = int(np.ceil((SCREEN_HEIGHT - bottom) * rows_per_pixel))
    return max(first, 0), min(stop, frame_size)


class CartPolePixels(Environment[CartPolePixelsState, CartPoleParams]):
    """CartPole (action ``Discrete(2)``: 0 pushes left, 1 right) observed as ``[frame_size,
    frame_size, frame_stack]`` uint8 frames, the newest last. A reset repeats its first frame
    ``frame_stack`` times. Params are CartPole's (they set the physics and the drawing scale)."""

    max_episode_steps = CartPole.max_episode_steps
    render_fps = CartPole.render_fps
    reset_option_params = CartPole.reset_option_params

    def __init__(
        self,
        frame_size: int = 84,
        frame_stack: int = 4,
        supersample: int = 4,
        sutton_barto_reward: bool = False,
        kinematics_integrator: str = "euler",
    ):
        for name, value in (("frame_size", frame_size), ("frame_stack", frame_stack)):
            if int(value) < 1:
                raise ValueError(f"{name} must be >= 1, got {value}")
        if int(supersample) < 1:
            raise ValueError(f"supersample must be >= 1, got {supersample}")
        self.frame_size, self.frame_stack = int(frame_size), int(frame_stack)
        self.supersample = int(supersample)
        self.physics = CartPole(sutton_barto_reward, kinematics_integrator)

    @property
    def default_params(self) -> CartPoleParams:
        """The underlying CartPole's default params."""
        return self.physics.default_params

    def draw(self, physics: CartPoleState, params: CartPoleParams) -> Array:
        """The observation frame of one physics state: ``[frame_size, frame_size]`` uint8."""
        return draw_frame(physics.x, physics.theta, params, self.frame_size, self.supersample)

    def drawn_rows(self, params: CartPoleParams | None = None) -> tuple[int, int]:
        """``(first, stop)``: the frame rows anything is ever drawn on (``drawn_rows``)."""
        return drawn_rows(self.frame_size, self.default_params if params is None else params)

    def _start(self, physics: CartPoleState, params: CartPoleParams):
        frame = self.draw(physics, params)
        frames = jnp.repeat(frame[..., None], self.frame_stack, axis=-1)
        return CartPolePixelsState(time=physics.time, physics=physics, frames=frames), frames

    def reset_env(self, key: PRNGKey, params: CartPoleParams):
        """Reset the cart-pole and fill the frame stack with its first frame."""
        return self._start(self.physics.reset_env(key, params)[0], params)

    def state_from_vector(self, vector: Array, params: CartPoleParams | None = None):
        """``vector = [x, x_dot, theta, theta_dot]``, as gymnasium's ``env.unwrapped.state``."""
        params = self.default_params if params is None else params
        return self._start(self.physics.state_from_vector(vector, params)[0], params)

    def state_to_vector(self, state: CartPolePixelsState) -> Array:
        """The cart-pole's physical state vector (the frames are derived from it)."""
        return self.physics.state_to_vector(state.physics)

    def step_env(
        self, key: PRNGKey, state: CartPolePixelsState, action: Array, params: CartPoleParams
    ):
        """Step the cart-pole, draw the new frame and push it onto the stack (oldest frame out).

        Reward and termination are CartPole's own.
        """
        physics, _, reward, terminated, info = self.physics.step_env(
            key, state.physics, action, params
        )
        newest = self.draw(physics, params)[..., None]
        frames = jnp.concatenate([state.frames[..., 1:], newest], axis=-1)
        new_state = CartPolePixelsState(time=physics.time, physics=physics, frames=frames)
        return new_state, frames, reward, terminated, info

    def observation_space(self, params: CartPoleParams | None = None) -> Box:
        """``frame_stack`` grey ``frame_size x frame_size`` frames, uint8, newest last."""
        shape = (self.frame_size, self.frame_size, self.frame_stack)
        return Box(0, 255, shape, np.dtype(np.uint8))

    def action_space(self, params: CartPoleParams | None = None) -> Discrete:
        """Two actions: 0 pushes left, 1 pushes right."""
        return Discrete(2)

    def render(self, state: CartPolePixelsState, params: CartPoleParams | None = None):
        """The full-size RGB frame of the cart-pole (what a person watches, not the agent)."""
        return self.physics.render(state.physics, params)
