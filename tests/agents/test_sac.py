"""SAC: the squashed Gaussian's maths against numeric references, the losses on networks and
their gradients, the probe envs end to end, the network options, the recipes, what became of
CrossQ's former SAC settings, and the command line. The pure maths alone is in
``test_sac_parts.py``."""

import dataclasses
import functools
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import rl_jax
import rl_jax.envs.core.probes  # noqa: F401  (registers the probe ids)
from rl_jax.agents import sac as sac_module
from rl_jax.agents.actor_critic import CriticBatch
from rl_jax.agents.sac import Config, Hyperparams, sac
from rl_jax.envs.core.probes import Truncation
from rl_jax.envs.core.spaces import Box
from rl_jax.errors import RunError, UsageError
from rl_jax.run import field_docs
from rl_jax.run.run_dir import identity_hash
from rl_jax.training import networks, squashed_gaussian
from rl_jax.training.params import dataclass_from_dict

ROOT = Path(__file__).resolve().parents[2]
PENDULUM = "rl_jax/Pendulum-v1"


# ---- the squashed Gaussian -----------------------------------------------------------------------
def test_tanh_log_prob_is_the_change_of_variables():
    """log pi(tanh(u)) = log N(u) - log |det d tanh / du|, the Jacobian taken by jax.jacfwd."""
    key = jax.random.key(0)
    mean, log_std, eps = jax.random.normal(key, (3, 4, 3))
    log_std = 0.5 * log_std
    u = mean + jnp.exp(log_std) * eps
    for row in range(4):
        jacobian = jax.jacfwd(jnp.tanh)(u[row])
        gaussian = jax.scipy.stats.norm.logpdf(u[row], mean[row], jnp.exp(log_std[row])).sum()
        expected = gaussian - jnp.linalg.slogdet(jacobian)[1]
        got = squashed_gaussian.log_prob(u[row], mean[row], log_std[row])
        np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-5)


def test_tanh_correction_is_exact_where_the_direct_form_fails():
    u = jnp.array([-15.0, -3.0, 0.0, 0.5, 9.0, 15.0])
    reference = np.log1p(-(np.tanh(np.asarray(u, np.float64)) ** 2))
    got = squashed_gaussian.tanh_log_det_jacobian(u)
    np.testing.assert_allclose(got, reference, rtol=1e-5)
    with np.errstate(divide="ignore"):  # what the stable form avoids: log(0)
        assert np.isinf(np.log(1.0 - np.tanh(np.float32(15.0)) ** 2))


def test_samples_follow_the_density():
    """A histogram of sampled actions against pi(a) = exp(log_prob(atanh(a))), and the sample's
    own log pi against log_prob of its pre-tanh value."""
    mean, log_std = jnp.full((200_000, 1), 0.4), jnp.full((200_000, 1), -0.3)
    a, log_pi = squashed_gaussian.sample(jax.random.key(1), mean, log_std)
    assert float(jnp.max(jnp.abs(a))) < 1.0
    u = jnp.arctanh(a[:1000])
    np.testing.assert_allclose(
        log_pi[:1000], squashed_gaussian.log_prob(u, mean[:1000], log_std[:1000]), atol=2e-4
    )
    counts, edges = np.histogram(np.asarray(a[:, 0]), bins=40, range=(-0.95, 0.95))
    centres = jnp.asarray((edges[:-1] + edges[1:]) / 2)[:, None]
    density = jnp.exp(squashed_gaussian.log_prob(jnp.arctanh(centres), mean[:40], log_std[:40]))
    expected = np.asarray(density) * (edges[1] - edges[0]) * a.shape[0]
    np.testing.assert_allclose(counts, expected, rtol=0.06, atol=60)


def squashed_entropy(mean: float, log_std: float) -> float:
    """H of tanh(N(mean, std)) by quadrature over u (float64): H_gauss + E[log(1 - tanh^2 u)]."""
    std = np.exp(log_std)
    u = np.linspace(mean - 12 * std, mean + 12 * std, 200_001)
    gauss = np.exp(-0.5 * ((u - mean) / std) ** 2) / (std * np.sqrt(2 * np.pi))
    log_det = 2.0 * (np.log(2.0) - u - np.logaddexp(0.0, -2.0 * u))
    return float(0.5 * np.log(2 * np.pi * np.e * std**2) + np.trapezoid(gauss * log_det, u))


@pytest.mark.parametrize("mean, log_std", [(0.0, 0.0), (0.8, -1.0), (-1.5, 0.5)])
def test_entropy_estimate_matches_quadrature(mean, log_std):
    shape = (400_000, 1)
    _, log_pi = squashed_gaussian.sample(
        jax.random.key(2), jnp.full(shape, mean), jnp.full(shape, log_std)
    )
    estimate = float(squashed_gaussian.entropy_estimate(log_pi))
    assert estimate == pytest.approx(squashed_entropy(mean, log_std), abs=0.01)


def test_rescale_maps_the_unit_box_onto_the_bounds():
    a = jnp.array([[-1.0, -1.0], [0.0, 0.0], [1.0, 1.0]])
    got = squashed_gaussian.rescale(a, np.array([-2.0, 0.0]), np.array([2.0, 1.0]))
    np.testing.assert_allclose(got, [[-2.0, 0.0], [0.0, 0.5], [2.0, 1.0]])


# ---- losses on networks --------------------------------------------------------------------------
ACTION_SPACE = Box(np.array([-2.0, 0.0]), np.array([2.0, 1.0]), (2,))


def _network_setup(dtype=jnp.float32):
    config = Config(
        env_id="unused", actor_hidden=(8,), critic_hidden=(8,), compute_dtype=jnp.dtype(dtype).name
    )
    nets = sac_module.build_networks(config, ACTION_SPACE)
    keys = jax.random.split(jax.random.key(3), 6)
    obs = jax.random.normal(keys[0], (5, 3), dtype)
    variables = dict(nets.actor.init(keys[1], obs))
    critics = dict(networks.init_stacked(nets.critic, keys[2], 2, obs, jnp.zeros((5, 2), dtype)))
    to = lambda tree: jax.tree.map(lambda x: x.astype(dtype), tree)  # noqa: E731
    batch = CriticBatch(
        obs=obs,
        action=jax.random.uniform(keys[3], (5, 2), dtype, 0.0, 1.0),
        r_t=jax.random.normal(keys[4], (5,), dtype),
        discount_t=jnp.array([0.9, 0.9, 0.0, 0.9, 0.0], dtype),
        next_obs=jax.random.normal(keys[5], (5, 3), dtype),
    )
    return nets, to(variables), to(critics), batch


def test_network_losses_check_grads():
    # ReLU kinks and float32 rounding make finite differences of whole networks unreliable, so
    # this runs in float64 (locally; library code stays float32).
    with jax.enable_x64(True):
        nets, actor, critics, batch = _network_setup(jnp.float64)
        key, alpha = jax.random.key(4), jnp.float64(0.2)

        def critic_objective(c):
            return sac_module.critic_loss_fn(c, critics, actor, batch, key, alpha, nets)[0]

        def actor_objective(a):
            return sac_module.actor_loss_fn(a, critics, batch.obs, key, alpha, nets)[0]

        check_grads(jax.jit(critic_objective), (critics,), order=1, modes=("rev",), eps=1e-6)
        check_grads(jax.jit(actor_objective), (actor,), order=1, modes=("rev",), eps=1e-6)


def test_critic_gradient_reaches_only_the_online_critics():
    """The bootstrap action is data (no gradient to the actor), and so are the target critics'
    values."""
    nets, actor, critics, batch = _network_setup()
    key, alpha = jax.random.key(5), jnp.float32(0.2)

    def loss(online, target, actor):
        return sac_module.critic_loss_fn(online, target, actor, batch, key, alpha, nets)[0]

    # compiled: op by op, each of the networks' and the gradient's ops compiles on its own
    grads = jax.jit(jax.grad(loss, argnums=(0, 1, 2)))
    online, target, actor_grads = grads(critics, critics, actor)
    assert all(np.all(np.asarray(g) == 0.0) for g in jax.tree.leaves(target))
    assert all(np.all(np.asarray(g) == 0.0) for g in jax.tree.leaves(actor_grads))
    assert any(np.any(np.asarray(g) != 0.0) for g in jax.tree.leaves(online))


# ---- probe envs, end to end ----------------------------------------------------------------------
GAMMA, TOL, CHUNKS = 0.5, 0.05, 6
FIXED_ALPHA = 0.5
PROBE_CONFIG = {
    "num_envs": 8,
    "learning_starts": 256,
    "batch_size": 64,
    "buffer_size": 16_384,
    "iterations_per_chunk": 250,
    "actor_hidden": (32, 32),
    "critic_hidden": (32, 32),
}
# A short horizon (gamma 0.5) and fast targets (tau 0.05) let values converge in ~1,500 updates;
# log(alpha) at rate 1e-2 reaches its equilibrium within them (at 1e-3 it is still falling).
PROBE_HPARAMS = {"gamma": GAMMA, "tau": 0.05, "actor_lr": 1e-3, "critic_lr": 1e-3, "alpha_lr": 1e-2}


@functools.cache
def probe_run(env_id: str, fixed_alpha: bool = False, n_step: int = 1):
    """``(state, config, metrics of the last chunk)`` after ``CHUNKS`` chunks of one seed; with
    ``fixed_alpha`` the temperature stays at ``FIXED_ALPHA``."""
    extra = {"learn_temperature": False} if fixed_alpha else {}
    config = sac.default_config(env_id, **PROBE_CONFIG, n_step=n_step, **extra)
    alpha = {"initial_alpha": FIXED_ALPHA} if fixed_alpha else {}
    hparams = sac.default_hyperparams(**PROBE_HPARAMS, **alpha)
    state = sac.init(jax.random.key(0), config, hparams)
    chunk = jax.jit(sac.train_chunk, static_argnums=1)
    for _ in range(CHUNKS):
        state, metrics = chunk(state, config, hparams)
    return state, config, metrics


def q_values(state, config, obs_values, action_values):
    obs = jnp.asarray(obs_values, jnp.float32)[:, None]
    actions = jnp.asarray(action_values, jnp.float32)[:, None]
    nets = sac_module.make_networks(config)
    return sac_module.critic_values(nets, state.agent.critics, obs, actions)


def policy_entropy(state, config, obs_value) -> float:
    """The learned policy's entropy at one observation, by quadrature."""
    nets = sac_module.make_networks(config)
    obs = jnp.array([[obs_value]], jnp.float32)
    mean, log_std = sac_module.actor_outputs(nets, state.agent.actor, obs)
    return squashed_entropy(float(mean[0, 0]), float(log_std[0, 0]))


def test_learns_constant_value():
    state, config, metrics = probe_run("rl_jax/ProbeConstantReward-v0")
    q = q_values(state, config, [0.0] * 5, np.linspace(-1, 1, 5))
    np.testing.assert_allclose(q, 1.0, atol=TOL)
    assert float(metrics.eval_return) == 1.0


def test_learns_best_action_and_tunes_the_temperature():
    state, config, metrics = probe_run("rl_jax/ProbeActionReward-v0")
    action = sac.policy(state, config)(jnp.zeros((1, 1)))
    assert float(action[0, 0]) == pytest.approx(0.5, abs=TOL)
    # Inside the bounds: after the warm-up few actions reach +-1, where the critics extrapolate.
    actions = np.array([-0.6, 0.0, 0.5, 0.8])
    q = q_values(state, config, [0.0] * 4, actions)
    np.testing.assert_allclose(q, np.broadcast_to(1 - (actions - 0.5) ** 2, q.shape), atol=TOL)
    # The temperature moved from 1 to hold the entropy near its target, -|A| = -1.
    assert float(jnp.exp(state.agent.log_alpha)) < 0.5
    assert policy_entropy(state, config, 0.0) == pytest.approx(-1.0, abs=0.1)
    assert int(state.agent.alpha_opt.count) == int(state.clock.updates)


def test_learns_soft_two_step_values():
    """Q(1, .) = 1 (terminal); Q(0, .) = gamma (1 + alpha H(pi(.|1))): the soft value of the
    next state carries the policy's entropy there."""
    state, config, _ = probe_run("rl_jax/ProbeTwoStep-v0", fixed_alpha=True)
    assert float(jnp.exp(state.agent.log_alpha)) == pytest.approx(FIXED_ALPHA)
    expected = [GAMMA * (1.0 + FIXED_ALPHA * policy_entropy(state, config, 1.0)), 1.0]
    q = q_values(state, config, [0.0, 1.0], [0.3, -0.3])
    np.testing.assert_allclose(q, np.broadcast_to(expected, q.shape), atol=TOL)


def soft_truncation_values(h0: float, h1: float, terminal: bool) -> list[float]:
    """Q(0), Q(1) of the truncation probes with the entropy bonus ``alpha H`` at each obs."""
    if terminal:
        return [0.0, 1.0]
    c0, c1 = GAMMA * FIXED_ALPHA * h1, GAMMA * FIXED_ALPHA * h0
    q0 = (GAMMA + GAMMA * c1 + c0) / (1.0 - GAMMA**2)
    return [q0, 1.0 + GAMMA * q0 + c1]


@pytest.mark.parametrize(
    ("env_id", "n_step"),
    [
        ("rl_jax/ProbeTruncation-v0", 1),
        ("rl_jax/ProbeTruncation-v0", 3),
        ("rl_jax/ProbeTermination-v0", 1),
    ],
)
def test_bootstraps_through_truncation_not_termination(env_id, n_step):
    """One-step episodes cut by the time limit (bootstrap from the true final obs) or ended in a
    terminal state (no bootstrap); 3-step windows must stop at the truncation the same way.

    No SAC run of 3-step windows on the termination probe: there the target is the reward
    alone, with nothing of SAC's (no soft bootstrap), and the windows that stop at a termination
    are the replay's, shared with TD3 (``actor_critic``): tests/agents/test_dqn_losses.py checks
    them and tests/agents/test_td3_probes.py trains 3-step TD3 on both probes."""
    state, config, _ = probe_run(env_id, fixed_alpha=True, n_step=n_step)
    terminal = env_id.endswith("Termination-v0")
    h0, h1 = (policy_entropy(state, config, p) for p in (0.0, 1.0))
    expected = soft_truncation_values(h0, h1, terminal)
    q = q_values(state, config, [0.0, 1.0], [0.2, -0.2])
    np.testing.assert_allclose(q, np.broadcast_to(expected, q.shape), atol=TOL)
    # The wrong answers are far: the flags swapped, or the entropy bonus left out.
    wrong = [soft_truncation_values(h0, h1, not terminal)]
    wrong.append([Truncation.true_q(p, GAMMA, terminal) for p in (0.0, 1.0)])
    for values in wrong[: 1 if terminal else 2]:
        assert np.max(np.abs(np.asarray(values) - np.asarray(expected))) > 3 * TOL


# ---- the network options, tiny ------------------------------------------------------------------
TINY_LOOP = {
    "num_envs": 2,
    "updates_per_iteration": 2,
    "iterations_per_chunk": 100,
    "batch_size": 32,
    "learning_starts": 64,
    "buffer_size": 1_000,
}


def tiny_run(recipe=None, **overrides):
    """``(state, metrics)`` after one chunk of 100 iterations on Pendulum."""
    config = sac.default_config("rl_jax/Pendulum-v1", recipe, **TINY_LOOP, **overrides)
    hparams = sac.default_hyperparams("rl_jax/Pendulum-v1", recipe)
    # init compiled too: op by op, SimBa's initialisation compiles each of its many ops alone
    state = jax.jit(sac.init, static_argnums=1)(jax.random.key(0), config, hparams)
    state, metrics = jax.jit(sac.train_chunk, static_argnums=1)(state, config, hparams)
    assert all(np.all(np.isfinite(np.asarray(x))) for x in jax.tree.leaves(state.agent))
    assert np.isfinite(float(metrics.eval_return)) and np.isfinite(metrics.extra["q"])
    assert int(state.clock.updates) == 2 * (100 - 32)
    return state, config


@pytest.mark.parametrize(
    "options",
    [
        {"network": "simba", "actor_hidden": (16,), "critic_hidden": (16, 16)},
        {"critic_norm": "layer", "actor_norm": "layer", "n_step": 3, "actor_hidden": (16,)},
    ],
    ids=["simba", "layer-norm-n-step"],
)
def test_network_options_run(options):
    state, config = tiny_run(**{"critic_hidden": (16,), **options})
    agent = state.agent
    assert (agent.obs_stats is not None) == (config.network == "simba")
    if config.network == "simba":  # every observation acted on, warm-up included
        assert float(agent.obs_stats.count) == pytest.approx(2 * 100, rel=1e-3)
    else:
        assert "LayerNorm_0" in agent.critics["params"]["MLP_0"]


# ---- recipes and the command line ---------------------------------------------------------------
def test_recipes_build_valid_configs():
    for env_id in ("rl_jax/Pendulum-v1", "rl_jax/HalfCheetah-v5", "rl_jax/Humanoid-v5"):
        for name in sac.recipes.names(env_id):
            sac.default_config(env_id, recipe=name)
            sac.default_hyperparams(env_id, recipe=name)
    paper = sac.default_config("rl_jax/Hopper-v5", recipe="sac-paper")
    assert (paper.num_envs, paper.updates_per_iteration, paper.batch_size) == (1, 1, 256)
    cpu = sac.default_config("rl_jax/HalfCheetah-v5")
    assert cpu.critic_hidden == cpu.actor_hidden == (128, 128) and cpu.batch_size == 128
    # Ant's recipe is the same but for Adam's b1 (0.5 against 0.9).
    ant = sac.default_config("rl_jax/Ant-v5")
    assert ant == dataclasses.replace(cpu, env_id="rl_jax/Ant-v5", adam_b1=0.5)
    assert cpu.adam_b1 == sac.default_config("rl_jax/Humanoid-v5").adam_b1 == 0.9
    assert float(sac.default_hyperparams("rl_jax/HalfCheetah-v5").critic_lr) == pytest.approx(1e-3)
    assert sac.default_config("rl_jax/Humanoid-v5").normalize_obs
    assert float(Hyperparams().as_arrays().target_entropy_per_dim) == -1.0
    # every field is a documented flag (env_id is the script's)
    assert field_docs.undocumented_fields(paper) == ["env_id"]
    assert field_docs.undocumented_fields(sac.default_hyperparams()) == []


def test_crossqs_former_sac_recipes_and_flags_say_what_to_type_instead():
    """CrossQ left SAC for a learner of its own: its recipe names, its norm, and the recorded
    settings of an old CrossQ run each say so in one line."""
    for recipe, instead in (
        ("crossq", "--algo crossq"),
        ("crossq-cpu", "--algo crossq --recipe cpu"),
    ):
        with pytest.raises(UsageError, match=f"--recipe {recipe}: .*{instead}"):
            sac.default_config("rl_jax/HalfCheetah-v5", recipe=recipe)
        assert recipe not in sac.recipes.names("rl_jax/HalfCheetah-v5")
    with pytest.raises(ValueError, match="critic_norm must be 'none' or 'layer'.*--algo crossq"):
        sac.default_config("rl_jax/Pendulum-v1", critic_norm="batch_renorm")


def test_old_runs_load_where_their_crossq_settings_were_off():
    """A SAC run recorded before CrossQ left has ``target_networks``, ``renorm_warmup`` and the
    norms in its config.json: off, it loads as SAC (the path runs load through); a CrossQ run
    says that it is one."""
    config = sac.default_config("rl_jax/Pendulum-v1")
    recorded = {**config.to_dict(), "target_networks": True, "renorm_warmup": 100_000}
    assert dataclass_from_dict(config, recorded) == config
    crossq_run = {**recorded, "critic_norm": "batch_renorm", "target_networks": False}
    with pytest.raises(RunError, match="target_networks, which is now the crossq learner's, so"):
        dataclass_from_dict(config, crossq_run)
    with pytest.raises(RunError, match="critic_norm must be 'none' or 'layer' .*CrossQ's"):
        dataclass_from_dict(config, {**recorded, "critic_norm": "batch_renorm"})


def _as_recorded_while_crossq_was_sacs(run_dir: Path, **crossq) -> None:
    """The run's record as SAC wrote it while CrossQ was its option: with ``target_networks``
    and ``renorm_warmup`` (off, unless ``crossq`` sets them), the hashes to match."""
    path = run_dir / "config.json"
    record = json.loads(path.read_text())
    retired = {"target_networks": True, "renorm_warmup": 100_000, **crossq}
    record["identity"]["config"].update(retired)
    old, new = record["identity_hash"], identity_hash(record["identity"])
    record["identity_hash"] = new
    path.write_text(json.dumps(record, indent=2))
    for metadata in run_dir.glob("*/*/meta/metadata"):
        metadata.write_text(metadata.read_text().replace(old, new))


def test_a_run_recorded_while_crossq_was_sacs_opens_and_resumes(tmp_path):
    run_dir, crossq_run = tmp_path / "run", tmp_path / "crossq"
    config = {**TINY_LOOP, "actor_hidden": (8, 8), "critic_hidden": (8, 8)}
    rl_jax.train("sac", PENDULUM, seeds=2, total_steps=400, out=run_dir, config=config, quiet=True)
    shutil.copytree(run_dir, crossq_run)
    _as_recorded_while_crossq_was_sacs(run_dir)
    action = np.asarray(rl_jax.open_run(run_dir).policy(seed=1)(np.zeros(3, np.float32)))
    assert action.shape == (1,) and np.all(np.abs(action) <= 2.0)
    assert rl_jax.resume(run_dir, total_steps=600, quiet=True).results.step == 600
    _as_recorded_while_crossq_was_sacs(crossq_run, target_networks=False)
    with pytest.raises(RunError, match="so this is a CrossQ run"):
        rl_jax.open_run(crossq_run).policy(seed=0)


@pytest.mark.slow  # ~7 s; SAC's CLI path is the one every learner shares (tests/run/test_cli.py)
def test_command_line_trains_pendulum(tmp_path):
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    command = [
        sys.executable,
        str(ROOT / "experiments" / "train.py"),
        "--algo",
        "sac",
        "--env",
        "rl_jax/Pendulum-v1",
        "--total-steps",
        "1500",
        "--iterations-per-chunk",
        "125",
        "--out",
        str(tmp_path / "run"),
    ]
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "run" / "metrics.jsonl").read_text().count("eval_return") >= 3
