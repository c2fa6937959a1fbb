"""``python -m rl_jax.run.evaluate RUN_DIR``: each seed's policies on many fresh episodes.

A run evaluates its policy on ``num_eval_envs`` episodes (10 by default) at every chunk, and
keeps the policy of each seed's best evaluation in ``best/``: the best of many small samples, so
its recorded return is optimistic. This evaluates the kept policies again, on ``--episodes`` new
episodes each (100 by default, all stepped together in one compiled loop, with env keys no
training evaluation used), and prints per seed the run's own figure beside the mean, spread and
range of the new episodes. ``--latest`` adds each seed's latest checkpoint. A run of a learner
of your own needs ``--algo`` naming it again, as it was trained with.

``--gymnasium`` plays the same policies in gymnasium's own env instead (``gymnasium.make`` of the
run's env: ``HalfCheetah-v5`` for ``rl_jax/HalfCheetah-v5``, ``ID`` for ``gymnasium:ID``, with
the run's env keywords), stepped on the host one episode at a time, seeded ``KEY + episode``:
evidence, from code we did not write, that the policy learned the task and not a quirk of our
copy of the env. A velocity-masked id (``rl_jax/CartPoleNoVel-v1``, ``rl_jax/Hopper-P-v5``, ...:
envs/memory/masked.py) plays in gymnasium's base env under the same mask (``gymnasium_twin``),
a recurrent policy reset at every episode.

``--gymnax`` plays them in gymnax's own env, for a run on a MinAtar id (``envs.MINATAR_IDS``):
``gymnax.make(NAME)`` for ``rl_jax/NAME``, stepped through gymnax's own ``reset`` and ``step``
(which merges both episode ends into ``done``) in one compiled loop, each observation given to
the policy as our adapter gives it (cast to float32), with the episode keys of the run's-env
evaluation above: equal tables say that our copy plays gymnax's game.

    python -m rl_jax.run.evaluate runs/results/dqn-cartpole-pixels --episodes 100 --latest
    python -m rl_jax.run.evaluate runs/ppo_hopper --gymnasium --episodes 20
    python -m rl_jax.run.evaluate runs/pqn_breakout --gymnax
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, cast

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np

from rl_jax import envs
from rl_jax.envs.memory import masked
from rl_jax.errors import OneLineParser, UsageError, exit_now, guard, positive_int
from rl_jax.run.api import evaluate_policy as returns_of
from rl_jax.run.policy import (
    LoadedPolicy,
    Policy,
    RecurrentPolicy,
    add_run_choice,
    command_line_env,
    command_line_learner,
)
from rl_jax.training.algorithm import (
    Algorithm,
    PolicyFn,
    PolicyState,
    RecurrentPolicyFn,
    TakesEnvKeywords,
)
from rl_jax.training.episodes import batched_policy_state
from rl_jax.training.jax_setup import configure

KEY = 20_251_125  # evaluation episodes' key: none of a run's own evaluations draws it
# Keywords of our envs' constructors that gymnasium's do not take: how we simulate, not what.
OWN_KEYWORDS = frozenset({"backend", "fidelity", "nthread"})


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """One policy's returns on fresh episodes, beside the run's own evaluation of it."""

    seed: int
    which: str  # "best" or "latest" (what was loaded)
    step: int  # env step of the policy
    run_eval: float | None  # the run's own evaluation of it
    returns: np.ndarray  # [episodes]
    env: str = ""  # where the episodes were played: "" for the run's env, else its twin's name
    library: str = "gymnasium"  # whose twin ``env`` is: "gymnasium" or "gymnax"


def evaluate_policy(loaded: LoadedPolicy, episodes: int, key: int = KEY) -> np.ndarray:
    """Returns ``[episodes]`` of ``loaded``'s deterministic policy in the run's env."""
    initial = loaded.initial_policy_state()
    return returns_of(loaded.env(), loaded.act(), jax.random.key(key), episodes, initial)


def gymnasium_id(env_id: str) -> str:
    """gymnasium's id of a run's env: ``ID`` of ``gymnasium:ID``; ``NAME`` of ``rl_jax/NAME``
    where gymnasium registers ``NAME`` (the MuJoCo v5 suite, CartPole, Pendulum)."""
    if env_id.startswith("gymnasium:"):
        return env_id.split(":", 1)[1]
    name = env_id.split(":")[-1].removeprefix("rl_jax/")
    if name == env_id or name not in gymnasium.registry:
        gymnax_hint = "; --gymnax replays them in gymnax's" if env_id in envs.MINATAR_IDS else ""
        raise UsageError(
            f"{env_id} has no twin registered in gymnasium to replay its policies in{gymnax_hint}"
        )
    return name


def gymnasium_returns(
    policy: Callable[[np.ndarray], np.ndarray],
    env_id: str,
    episodes: int,
    keywords: dict[str, Any] | None = None,  # gymnasium.make's, values of any type
    key: int = KEY,
) -> np.ndarray:
    """Returns ``[episodes]`` of ``policy`` in ``gymnasium.make(env_id, **keywords)``, episode
    ``i`` reset with seed ``key + i`` and played to termination or truncation."""
    env = gymnasium.make(env_id, **(keywords or {}))
    try:
        return _play(env, policy, episodes, key)
    finally:
        env.close()


def _play(
    env: gymnasium.Env, policy: Callable[[np.ndarray], np.ndarray], episodes: int, key: int
) -> np.ndarray:
    """``gymnasium_returns`` on an env already made."""
    returns = np.zeros(episodes)
    for episode in range(episodes):
        obs, _ = env.reset(seed=key + episode)
        if isinstance(policy, RecurrentPolicy):
            policy.reset()
        done = False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(policy(obs))
            returns[episode] += float(reward)
            done = bool(terminated or truncated)
    return returns


def gymnasium_twin(env_id: str, keywords: dict[str, object]) -> tuple[str, gymnasium.Env]:
    """gymnasium's own env for a run's ``env_id``, made with ``keywords``, and its name:
    ``gymnasium.make`` of ``gymnasium_id``, or for a masked id (envs/memory/masked.py) its base
    env under the same mask (``masked.gymnasium_twin``), named ``BASE masked as ID``."""
    name = env_id.split(":")[-1]
    if name in masked.GYMNASIUM_BASES:
        twin = masked.gymnasium_twin(name, **cast(dict[str, Any], keywords))
        return f"{masked.GYMNASIUM_BASES[name]} masked as {name}", twin
    twin_id = gymnasium_id(env_id)
    return twin_id, gymnasium.make(twin_id, **cast(dict[str, Any], keywords))


def _in_gymnasium(loaded: LoadedPolicy, episodes: int) -> tuple[str, np.ndarray]:
    """``loaded``'s policy in gymnasium's twin of the run's env: its name and the returns."""
    config = loaded.config
    keywords = envs.parse_keywords(
        config.env_kwargs if isinstance(config, TakesEnvKeywords) else ""
    )
    keywords = {name: value for name, value in keywords.items() if name not in OWN_KEYWORDS}
    policy = (
        RecurrentPolicy(loaded) if loaded.initial_policy_state() is not None else Policy(loaded)
    )
    env_id, env = gymnasium_twin(loaded.env_id, keywords)
    try:
        shape = tuple(env.observation_space.shape or ())
        if shape != policy.observation_shape:
            raise UsageError(
                f"gymnasium's {env_id} observes shape {shape}, the run's policy "
                f"{policy.observation_shape}: its episodes cannot be replayed there"
            )
        return env_id, _play(env, policy, episodes, KEY)
    finally:
        env.close()


# ---- gymnax --------------------------------------------------------------------------------------
class GymnaxEnv(Protocol):
    """What ``--gymnax`` calls of a gymnax ``Environment``: its own functional API (gymnax ships
    no type information). ``step`` resets inside where ``terminated | truncated``."""

    def reset(self, key: jax.Array, params: object) -> tuple[jax.Array, object]: ...

    def step(
        self, key: jax.Array, state: object, action: jax.Array, params: object
    ) -> tuple[jax.Array, object, jax.Array, jax.Array, jax.Array, dict[str, jax.Array]]: ...


def gymnax_name(env_id: str) -> str:
    """gymnax's name of a run's env: ``NAME`` of a MinAtar id ``rl_jax/NAME``
    (``envs.MINATAR_IDS``, our ids that wrap a gymnax env)."""
    if env_id not in envs.MINATAR_IDS:
        raise UsageError(
            f"{env_id} is not a gymnax env to replay its policies in: --gymnax takes a run on "
            + ", ".join(envs.MINATAR_IDS)
        )
    return env_id.removeprefix("rl_jax/")


def gymnax_twin(env_id: str, keywords: dict[str, object]) -> tuple[str, GymnaxEnv, object]:
    """gymnax's own env for a run's ``env_id`` made with ``keywords``: its name, the env and
    its params. ``gymnax.make(NAME)`` with gymnax's default params, which the run's keywords
    change as ``envs.from_gymnax`` applies them (a field of the params replaced, any other
    keyword given to ``gymnax.make``); none is the usual case.

    A run trained with ``sticky_actions`` > 0 (our keyword: the original MinAtar's repeated
    actions) is refused, not replayed without them: gymnax has none, so its episodes would be
    another game than the one the policy trained and was evaluated on, and its table beside the
    run's figures would say nothing about our copy of the env."""
    import gymnax  # here, not at the top: only the MinAtar runs need it

    name = gymnax_name(env_id)
    keywords = dict(keywords)
    sticky = keywords.pop("sticky_actions", 0.0)
    if sticky:
        raise UsageError(
            f"the run trained with sticky_actions={sticky}, and gymnax's {name} has no sticky "
            "actions: its episodes cannot be replayed there"
        )
    env, params = gymnax.make(name)
    fields = {field.name for field in dataclasses.fields(params)}
    constructor = {key: value for key, value in keywords.items() if key not in fields}
    if constructor:
        env, params = gymnax.make(name, **constructor)
    overrides = {key: value for key, value in keywords.items() if key in fields}
    return name, env, params.replace(**overrides) if overrides else params


def observation_as_ours(
    env: GymnaxEnv, params: object, space: envs.Space
) -> Callable[[jax.Array], jax.Array]:
    """One of gymnax's observations as our env gives it to the policy, whose observations are
    ``space``: cast to its dtype (our adapter's float32) and, for a policy that sees them
    flattened (``envs.FlattenObservation``), reshaped to its shape."""
    shape = tuple(space.shape)
    gymnax_shape = tuple(jax.eval_shape(env.reset, jax.random.key(0), params)[0].shape)
    if np.prod(gymnax_shape) != np.prod(shape):
        raise UsageError(
            f"gymnax observes shape {gymnax_shape}, the run's policy {shape}: its episodes "
            "cannot be replayed there"
        )
    return lambda obs: jnp.reshape(jnp.asarray(obs, space.dtype), shape)


def gymnax_returns(
    act: PolicyFn | RecurrentPolicyFn,
    env: GymnaxEnv,
    params: object,
    episodes: int,
    key: int = KEY,
    observe: Callable[[jax.Array], jax.Array] = jnp.asarray,
    initial_policy_state: PolicyState | None = None,
) -> np.ndarray:
    """Returns ``[episodes]`` of ``act`` (one observation -> its action; with
    ``initial_policy_state``, ``(policy_state, obs) -> (action, policy_state)``) in gymnax's
    ``env``, through gymnax's own ``reset(key, params)`` and ``step(key, state, action,
    params)``: all episodes vmapped in one jitted while loop, each counted until gymnax's end
    (terminated, or truncated at its ``max_steps_in_episode``). ``observe`` maps one of gymnax's
    observations to the policy's. The keys are those ``evaluate_policy`` draws from ``key``."""
    if initial_policy_state is None:
        feed_forward = cast(PolicyFn, act)

        def policy(state: PolicyState, obs: jax.Array) -> tuple[jax.Array, PolicyState]:
            return feed_forward(observe(obs)), state

        initial: PolicyState = ()
    else:
        recurrent = cast(RecurrentPolicyFn, act)

        def policy(state: PolicyState, obs: jax.Array) -> tuple[jax.Array, PolicyState]:
            return recurrent(state, observe(obs))

        initial = initial_policy_state
    reset = jax.vmap(env.reset, in_axes=(0, None))
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    #: (step, gymnax's states, policy states, observations, alive, returns)
    Loop = tuple[jax.Array, object, PolicyState, jax.Array, jax.Array, jax.Array]

    def run(key: jax.Array) -> jax.Array:
        reset_key, step_key = jax.random.split(key)

        def advance(carry: Loop) -> Loop:
            time, state, policy_state, obs, alive, total = carry
            action, policy_state = jax.vmap(policy)(policy_state, obs)
            keys = jax.random.split(jax.random.fold_in(step_key, time), episodes)
            obs, state, reward, terminated, truncated, _ = step(keys, state, action, params)
            total = total + jnp.where(alive, reward.astype(jnp.float32), 0.0)
            alive = jnp.logical_and(alive, ~jnp.logical_or(terminated, truncated))
            return time + 1, state, policy_state, obs, alive, total

        obs, state = reset(jax.random.split(reset_key, episodes), params)
        alive, total = jnp.ones(episodes, jnp.bool_), jnp.zeros(episodes, jnp.float32)
        policy_state = batched_policy_state(initial, episodes)
        carry: Loop = (jnp.int32(0), state, policy_state, obs, alive, total)
        return jax.lax.while_loop(lambda carry: jnp.any(carry[4]), advance, carry)[-1]

    return np.asarray(jax.jit(run)(jax.random.key(key)))


def _in_gymnax(loaded: LoadedPolicy, episodes: int) -> tuple[str, np.ndarray]:
    """``loaded``'s policy in gymnax's own env of the run's MinAtar id: its name and the
    returns, on the episode keys of ``evaluate_policy``."""
    config = loaded.config
    keywords = envs.parse_keywords(
        config.env_kwargs if isinstance(config, TakesEnvKeywords) else ""
    )
    name, env, params = gymnax_twin(loaded.env_id, keywords)
    observe = observation_as_ours(env, params, loaded.env().observation_space())
    initial = loaded.initial_policy_state()
    return name, gymnax_returns(loaded.act(), env, params, episodes, KEY, observe, initial)


def evaluate_run(
    run_dir: Path,
    episodes: int = 100,
    seeds: list[int] | None = None,
    config_index: int | None = None,
    latest: bool = False,
    algorithm: str | Algorithm | None = None,
    gymnasium: bool = False,
    env: str | None = None,
    gymnax: bool = False,
) -> list[Evaluation]:
    """Every seed's best policy (and its latest, with ``latest``) on ``episodes`` episodes of
    the run's env, or with ``gymnasium`` of gymnasium's own, with ``gymnax`` of gymnax's own;
    ``algorithm`` names the run's learner when it is not built in, ``env`` its env when it
    comes from a module of the user's own."""
    if gymnasium and gymnax:
        raise UsageError("--gymnasium and --gymnax: choose one env to replay the policies in")
    first = LoadedPolicy(run_dir, None, config_index, "latest", algorithm, env)
    evaluations = []
    for seed in first.seeds if seeds is None else seeds:
        for which in ("best", "latest") if latest else ("best",):
            loaded = LoadedPolicy(
                run_dir, seed, first.config_index, which, first.algorithm, first.env_id
            )
            if gymnasium or gymnax:
                twin, returns = (_in_gymnasium if gymnasium else _in_gymnax)(loaded, episodes)
            else:
                twin, returns = "", evaluate_policy(loaded, episodes)
            library = "gymnax" if gymnax else "gymnasium"
            evaluations.append(
                Evaluation(
                    seed, loaded.which, loaded.step, loaded.eval_return, returns, twin, library
                )
            )
    return evaluations


def table(evaluations: list[Evaluation]) -> str:
    """The evaluations as a text table: per policy its step, the run's eval and the fresh
    episodes' mean, std, min and max.
    """
    episodes = len(evaluations[0].returns)
    first = evaluations[0]
    where = first.env and f" of {first.library}'s {first.env}"
    lines = [
        f"each policy on {episodes} fresh episodes{where}",
        "",
        "  seed  policy        step   run's eval      mean      std       min       max",
        "  ----  ------  ----------   ----------  --------  -------  --------  --------",
    ]
    for e in evaluations:
        run_eval = "-" if e.run_eval is None else f"{e.run_eval:.1f}"
        r = e.returns
        lines.append(
            f"  {e.seed:4d}  {e.which:6s}  {e.step:10,d}   {run_eval:>10s}  {r.mean():8.1f}  "
            f"{r.std():7.1f}  {r.min():8.1f}  {r.max():8.1f}"
        )
    lines.append("")
    for which in dict.fromkeys(e.which for e in evaluations):
        means = [e.returns.mean() for e in evaluations if e.which == which]
        lines.append(f"  mean over seeds, {which}: {np.mean(means):.1f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None, prog: str = "python -m rl_jax.run.evaluate") -> int:
    """``python -m rl_jax.run.evaluate RUN_DIR``: run each seed's best (and with ``--latest``
    latest) policy on fresh episodes and print the table. Returns the exit status. ``prog`` is
    the command named in ``--help`` and errors (``rl-jax evaluate``).
    """
    parser = OneLineParser(prog=prog, description=__doc__.split("\n")[0])
    parser.add_argument("run_dir", type=Path, help="a run directory (holds config.json)")
    parser.add_argument(
        "--episodes", type=positive_int, default=100, help="episodes per policy (default: 100)"
    )
    add_run_choice(parser, "only this seed (default: every seed)")
    parser.add_argument(
        "--latest", action="store_true", help="also each seed's latest checkpoint's policy"
    )
    parser.add_argument(
        "--gymnasium",
        action="store_true",
        help="play the episodes in gymnasium's own env (HalfCheetah-v5 for "
        "rl_jax/HalfCheetah-v5; CartPole-v1 with the velocities zeroed for "
        "rl_jax/CartPoleNoVel-v1), stepped on the host",
    )
    parser.add_argument(
        "--gymnax",
        action="store_true",
        help="play the episodes in gymnax's own env (Breakout-MinAtar for "
        "rl_jax/Breakout-MinAtar: the MinAtar ids), on the keys of the run's-env evaluation",
    )
    args = parser.parse_args(argv)

    def run() -> int:
        configure()
        seeds = None if args.seed is None else [args.seed]
        learner = command_line_learner(args.run_dir, args.algo)  # first: it may register the env
        env_id = command_line_env(args.run_dir, args.env, learner)
        evaluations = evaluate_run(
            args.run_dir,
            args.episodes,
            seeds,
            args.config_index,
            args.latest,
            learner,
            args.gymnasium,
            env_id,
            args.gymnax,
        )
        print(table(evaluations))
        return 0

    return guard(run)


if __name__ == "__main__":
    # Run the imported module's main, not this __main__ copy, so that its exception classes are
    # the ones the guard knows.
    from rl_jax.run.evaluate import main as module_main

    exit_now(module_main())
