"""Watch a trained policy: a GIF of a run's deterministic policy (each seed's best evaluated
policy by default, ``--latest`` for the latest checkpoint's).

    python -m rl_jax.run.render RUN_DIR [--seed K] [--config I] [--episodes N] [--out FILE]
                                [--latest] [--algo LEARNER]

Without ``--out`` the GIF is ``RUN_DIR/policy.gif``, or, where that exists (the one ``--gif``
wrote at the end of the run, or an earlier rendering), the first free name of ``policy-2.gif``,
``policy-3.gif``, ...: a rendering never replaces a GIF unasked. ``--out FILE`` names the file
to write, and replaces it if it exists, saying so in the line it prints.

``--algo`` names the run's learner when it is one of your own (``rl_jax.run.learners``).

Frames come from the environment, through one of two hooks (the first one the env has):

* ``env.render_episode(states, params) -> list of (H, W, 3) uint8 frames`` for a whole episode
  (``states`` is the list of unbatched env states, first to last). An env that needs context
  across frames uses it: a MuJoCo env keeps one ``mujoco.Renderer`` open and follows the torso
  with its tracking camera.
* ``env.render(state, params) -> frame`` for one state (the ``Environment`` API).

A run of a learner that moves from the env's own positions (``position_policy``: AlphaZero on
``pgx/tic_tac_toe`` or ``pgx/connect_four``) is drawn as games instead (``render_game``): each
episode one game of the trained search against the run's evaluation opponent, the search opening
the odd games and moving second in the even ones, one frame per position
(``rl_jax.envs.games.draw``) and the final position held for a second.

An env with an ``episode_plot(states, params, path)`` hook also gets a plot of the last rendered
episode next to the GIF, as ``<name>_episode.png`` (the rocket's x(t), v(t) plot).

MuJoCo renders headless through EGL, else OSMesa (``envs.mujoco.opengl`` picks one when the
first frame is drawn, unless ``MUJOCO_GL`` chose); without an OpenGL backend the command says in
one line what to install.
"""

from __future__ import annotations

import contextlib
import math
import traceback
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, Protocol, cast, runtime_checkable

import imageio.v2 as imageio
import jax
import numpy as np
import numpy.typing as npt

from rl_jax.envs.core.core import Environment, TimeStep
from rl_jax.envs.core.preprocessing import ACTION_MASK, has_action_mask
from rl_jax.envs.core.wrappers import Wrapper
from rl_jax.errors import OneLineParser, RenderError, exit_now, guard, positive_int
from rl_jax.run import render_game
from rl_jax.run.policy import (
    LoadedPolicy,
    add_run_choice,
    command_line_env,
    command_line_learner,
)
from rl_jax.training.algorithm import Algorithm, PolicyFn, RecurrentPolicyFn
from rl_jax.training.jax_setup import configure

NO_OPENGL = (
    "no OpenGL backend for headless rendering: install EGL "
    "(apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri) and use MUJOCO_GL=egl, "
    "or OSMesa (apt-get install libosmesa6) with MUJOCO_GL=osmesa"
)
_GL_MARKERS = ("OpenGL", "EGL", "GLFW", "glGetError", "mjr_makeContext", "osmesa", "gladLoad")


# ---- rollouts and frames --------------------------------------------------------------------


def rollout(
    env: Environment,
    act: PolicyFn | RecurrentPolicyFn,
    key: jax.Array,
    episodes: int,
    initial_policy_state: object | None = None,
) -> list[dict[str, Any]]:
    """``episodes`` episodes of ``act`` in ``env``: per episode the states and total reward.
    With ``initial_policy_state`` (a recurrent policy's, one env's) ``act`` maps
    ``(policy_state, obs[, legal])`` to ``(action, policy_state)``, the state starting each
    episode from it."""
    if initial_policy_state is not None:
        recurrent = cast(RecurrentPolicyFn, act)
        return _recurrent_rollout(env, recurrent, key, episodes, initial_policy_state)
    params = env.default_params
    reset = jax.jit(lambda key: env.reset(key, params))
    masked = has_action_mask(env)  # then the policy is given each obs's legal actions
    act_legal = cast(Callable[..., jax.Array], act)

    def choose(obs: jax.Array, legal: jax.Array | None) -> jax.Array:
        return act_legal(obs) if legal is None else act_legal(obs, legal)

    step = jax.jit(lambda key, state, obs, legal: env.step(key, state, choose(obs, legal), params))
    results = []
    for _ in range(episodes):
        key, key_reset = jax.random.split(key)
        state, timestep = reset(key_reset)
        states, total = [jax.device_get(state)], 0.0
        for _ in range(env.max_episode_steps):
            key, key_step = jax.random.split(key)
            legal = timestep.info[ACTION_MASK] if masked else None
            state, timestep = step(key_step, state, timestep.obs, legal)
            states.append(jax.device_get(state))
            total += float(timestep.reward)
            if bool(timestep.terminated) or bool(timestep.truncated):
                break
        results.append({"states": states, "return": total})
    return results


def _recurrent_rollout(
    env: Environment,
    act: Callable[..., tuple[jax.Array, object]],
    key: jax.Array,
    episodes: int,
    initial: object,
) -> list[dict[str, object]]:
    """``rollout`` of a recurrent policy: its state starts every episode from ``initial``."""
    params = env.default_params
    reset = jax.jit(lambda key: env.reset(key, params))
    masked = has_action_mask(env)

    def choose(policy_state: object, obs: jax.Array, legal: jax.Array | None):
        return act(policy_state, obs) if legal is None else act(policy_state, obs, legal)

    def advance(
        key: jax.Array,
        state: object,
        policy_state: object,
        obs: jax.Array,
        legal: jax.Array | None,
    ) -> tuple[object, TimeStep, object]:
        action, policy_state = choose(policy_state, obs, legal)
        state, timestep = env.step(key, state, action, params)
        return state, timestep, policy_state

    step = jax.jit(advance)
    results = []
    for _ in range(episodes):
        key, key_reset = jax.random.split(key)
        state, timestep = reset(key_reset)
        policy_state = initial
        states, total = [jax.device_get(state)], 0.0
        for _ in range(env.max_episode_steps):
            key, key_step = jax.random.split(key)
            legal = timestep.info[ACTION_MASK] if masked else None
            state, timestep, policy_state = step(key_step, state, policy_state, timestep.obs, legal)
            states.append(jax.device_get(state))
            total += float(timestep.reward)
            if bool(timestep.terminated) or bool(timestep.truncated):
                break
        results.append({"states": states, "return": total})
    return results


def _innermost(
    env: Environment, states: list[Any], hook: str = "render_episode"
) -> tuple[Environment, list[Any]]:
    """Unwrap wrappers (whose state wraps the inner env's state in ``.env_state``) down to the
    first env with its own ``hook``, else the innermost env."""
    while isinstance(env, Wrapper) and not _has_own(env, hook):
        if states and hasattr(states[0], "env_state"):
            states = [state.env_state for state in states]
        env = env.env
    return env, states


def _has_own(env: Environment, name: str) -> bool:
    return any(name in vars(cls) for cls in type(env).__mro__)


@runtime_checkable
class RendersEpisodes(Protocol):
    """An env that draws a whole episode at once (its frames may depend on the episode's
    course, as the rocket's trail does) rather than one ``render(state)`` per state."""

    def render_episode(self, states: Sequence[object], params: object) -> Iterable[npt.ArrayLike]:
        """The episode's frames, ``(H, W, 3)`` uint8 each, from its states."""
        ...


@runtime_checkable
class PlotsEpisodes(Protocol):
    """An env that plots an episode's course beside its GIF (``policy_episode.png``)."""

    def episode_plot(self, states: Sequence[object], params: object, path: Path) -> None:
        """Saves a plot of the episode's course to ``path``."""
        ...


@contextlib.contextmanager
def opengl_errors() -> Iterator[None]:
    """Turn a missing OpenGL backend, at MuJoCo's import or at rendering, into ``RenderError``."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # GLFW reports a missing display as warnings first
            yield
    except RenderError:
        raise
    except Exception as error:
        if type(error).__name__ == "OpenGLUnavailableError":  # envs.mujoco.opengl's own line
            raise RenderError(str(error)) from None
        if _is_gl_failure(error):
            reason = (str(error).splitlines() or [type(error).__name__])[0][:120]
            raise RenderError(f"{NO_OPENGL} ({type(error).__name__}: {reason})") from None
        raise


def episode_frames(env: Environment, states: list[Any]) -> list[np.ndarray]:
    """Frames of one episode through the env's hooks (``render_episode`` or ``render``)."""
    inner, inner_states = _innermost(env, states)
    params = inner.default_params
    with opengl_errors():
        try:
            if isinstance(inner, RendersEpisodes):
                return [np.asarray(f) for f in inner.render_episode(inner_states, params)]
            return [np.asarray(inner.render(state, params)) for state in inner_states]
        except NotImplementedError:
            raise RenderError(f"{inner!r} has no renderer (render or render_episode)") from None


def _is_gl_failure(error: BaseException) -> bool:
    text = f"{type(error).__module__}.{type(error).__name__}: {error}"
    if any(marker.lower() in text.lower() for marker in _GL_MARKERS):
        return True
    files = [frame.filename for frame in traceback.extract_tb(error.__traceback__)]
    return any(
        part in name
        for name in files
        for part in ("/OpenGL/", "/glfw/", "mujoco/egl", "mujoco/osmesa", "mujoco/glfw")
    )


def _fps(env: Environment) -> float:
    """Playback rate: the env's ``render_fps``, else ``1 / params.dt``, else 30."""
    fps = getattr(env, "render_fps", None) or (getattr(env, "metadata", None) or {}).get(
        "render_fps"
    )
    if fps:
        return float(fps)
    dt = getattr(env.default_params, "dt", None)
    return float(1.0 / float(dt)) if dt is not None and float(dt) > 0 else 30.0


#: The GIF ``--gif`` writes at the end of a run, and ``render``'s first choice of name.
GIF_FILE = "policy.gif"
#: GIF players round frame delays below 20 ms up to 100 ms: faster envs skip frames instead.
MAX_GIF_FPS = 50.0


def save_gif(frames: list[np.ndarray], path: Path, fps: float, max_frames: int = 600) -> None:
    """Write frames as a looping GIF in real time; long episodes keep every k-th frame."""
    every = max(1, math.ceil(len(frames) / max_frames), math.ceil(fps / MAX_GIF_FPS))
    kept: list[npt.ArrayLike] = [np.asarray(frame, np.uint8) for frame in frames[::every]]
    imageio.mimsave(path, kept, duration=1000.0 * every / fps, loop=0)


def write_gif(
    run_dir: str | Path,
    seed: int | None = None,
    episodes: int = 1,
    out: str | Path | None = None,
    config_index: int | None = None,
    max_frames: int = 600,
    which: str = "best",
    algorithm: str | Algorithm | None = None,
    env: str | None = None,
) -> Path:
    """Render the deterministic policy of (config, seed) of ``run_dir`` to a GIF; its path.
    ``which``: the seed's best evaluated policy ("best") or its latest checkpoint ("latest");
    ``algorithm``: the run's learner, when it is not built in; ``env``: the run's env, when it
    comes from a module of the user's own. A learner with a ``position_policy`` (a board game)
    plays ``episodes`` games against its evaluation opponent (``render_game``)."""
    with opengl_errors():  # a MuJoCo env may import mujoco (and fail) while being built
        loaded = LoadedPolicy(Path(run_dir), seed, config_index, which, algorithm, env)
        if render_game.plays_positions(loaded):
            return _write_game_gif(loaded, episodes, out, max_frames)
        played = loaded.env()
        act = loaded.act()
        initial = loaded.initial_policy_state()
        episodes_data = rollout(played, act, jax.random.key(loaded.seed), episodes, initial)
        frames = [f for episode in episodes_data for f in episode_frames(played, episode["states"])]
        path = Path(out) if out is not None else free_gif_path(Path(run_dir))
        replaced = path.exists()
        save_gif(frames, path, _fps(played), max_frames)
        plot_path = _save_episode_plot(played, episodes_data[-1]["states"], path)
    returns = ", ".join(f"{episode['return']:.1f}" for episode in episodes_data)
    plot_note = f" (episode plot: {plot_path})" if plot_path else ""
    if loaded.note:
        print(f"note: {loaded.note}")
    print(
        f"rendered seed {loaded.seed} (config {loaded.config_index}) at step {loaded.step:,}, "
        f"its {loaded.which} policy: episode return {returns}; {len(frames)} frames -> "
        f"{path}{' (replaced the file that was there)' if replaced else ''}{plot_note}"
    )
    return path


def _write_game_gif(
    loaded: LoadedPolicy, episodes: int, out: str | Path | None, max_frames: int
) -> Path:
    """``write_gif`` for a learner that moves from positions: games against its opponent."""
    frames, games, opponent = render_game.play_and_draw(loaded, episodes)
    path = Path(out) if out is not None else free_gif_path(loaded.run_dir)
    replaced = path.exists()
    save_gif(frames, path, render_game.MOVES_PER_SECOND, max_frames)
    if loaded.note:
        print(f"note: {loaded.note}")
    print(
        f"rendered seed {loaded.seed} (config {loaded.config_index}) at step {loaded.step:,}, "
        f"its {loaded.which} policy {render_game.summary(games, opponent)}; {len(frames)} "
        f"frames -> {path}{' (replaced the file that was there)' if replaced else ''}"
    )
    return path


def free_gif_path(run_dir: Path) -> Path:
    """``run_dir/policy.gif``, or the first of ``policy-2.gif``, ``policy-3.gif``, ... that does
    not exist: a rendering without ``--out`` writes a new file, never over one."""
    path, number = run_dir / GIF_FILE, 1
    while path.exists():
        number += 1
        path = run_dir / f"{Path(GIF_FILE).stem}-{number}{Path(GIF_FILE).suffix}"
    return path


def _save_episode_plot(env: Environment, states: list[Any], gif_path: Path) -> Path | None:
    inner, inner_states = _innermost(env, states, "episode_plot")
    if not isinstance(inner, PlotsEpisodes):
        return None
    path = gif_path.with_name(gif_path.stem + "_episode.png")
    inner.episode_plot(inner_states, inner.default_params, path)
    return path


def main(argv: list[str] | None = None, prog: str = "python -m rl_jax.run.render") -> int:
    """``python -m rl_jax.run.render RUN_DIR``: render a seed's policy to a GIF. Returns the exit
    status. ``prog`` is the command named in ``--help`` and errors (``rl-jax render``).
    """
    parser = OneLineParser(prog=prog, description=__doc__.split("\n")[0])
    parser.add_argument("run_dir", type=Path, help="a run directory (holds config.json)")
    add_run_choice(parser, "seed to render (default: the one with the best eval return)")
    parser.add_argument(
        "--episodes",
        type=positive_int,
        default=1,
        help="episodes, or games of a board-game run (default: 1)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="GIF path, replaced if it exists (default: RUN_DIR/policy.gif, or where that "
        "exists the first free policy-2.gif, policy-3.gif, ...: never an existing file)",
    )
    parser.add_argument(
        "--max-frames",
        type=positive_int,
        default=600,
        help="longer episodes keep every k-th frame (default: 600)",
    )
    parser.add_argument(
        "--latest",
        action="store_true",
        help="render the latest checkpoint's policy (default: each seed's best evaluated one)",
    )
    args = parser.parse_args(argv)

    def render() -> int:
        configure()
        learner = command_line_learner(args.run_dir, args.algo)  # first: it may own the env
        write_gif(
            args.run_dir,
            args.seed,
            args.episodes,
            args.out,
            args.config_index,
            args.max_frames,
            "latest" if args.latest else "best",
            learner,
            command_line_env(args.run_dir, args.env, learner),
        )
        return 0

    return guard(render)


if __name__ == "__main__":
    # Run the imported module's main, not this __main__ copy, so that its exception classes are
    # the ones the guard knows.
    from rl_jax.run.render import main as module_main

    exit_now(module_main())
