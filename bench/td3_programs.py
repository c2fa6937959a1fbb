"""The programs ``bench_td3`` times, and their exact matmul FLOP counts.

Kept apart from ``bench_td3`` because they run in a child process: the CPU must be split into
two JAX devices (``rl_jax.training.jax_setup.configure(cpu_devices=2)``) before JAX starts, and the
benchmark driver's own process has started JAX already.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend import core as jax_core
from jax.sharding import Mesh, PartitionSpec

from rl_jax.agents import td3 as td3_module
from rl_jax.agents.actor_critic import CriticBatch
from rl_jax.agents.td3 import td3
from rl_jax.training import replay

ENV_ID = "rl_jax/HalfCheetah-v5"
MATMUL_SIZE = 1024
MATMUL_CHAIN = 16  # matmuls per timed call, so dispatch is noise


# ---- FLOP counting ------------------------------------------------------------------------------
# A TD3 update's arithmetic is its matrix products: every dense layer of the forward pass is one
# [B, n_in] x [n_in, n_out] product (2 B n_in n_out FLOPs), and the backward pass adds the weight
# gradient (x^T dy, same size) and, below the top layer of the differentiated path, the input
# gradient (dy W^T, same size again). Rather than transcribing that by hand (and getting the
# first-layer input gradient, the twin critics and the target networks' forward-only passes
# wrong), we count every ``dot_general`` in the jaxpr that jax traces for the update, which is
# exactly what XLA runs: 2 x batch x M x N x K per product. Elementwise work (ReLU, tanh, Adam,
# Polyak averaging, the loss) is O(parameters + B x width), under 2% of the products at 256 x
# 256 and batch 256, and is left out, as a matmul roofline does.
def _dot_flops(equation: Any) -> int:
    lhs, rhs = (v.aval for v in equation.invars)
    (lhs_contract, rhs_contract), (lhs_batch, rhs_batch) = equation.params["dimension_numbers"]
    contract = math.prod(lhs.shape[d] for d in lhs_contract)
    batch = math.prod(lhs.shape[d] for d in lhs_batch)
    rows = math.prod(s for d, s in enumerate(lhs.shape) if d not in (*lhs_contract, *lhs_batch))
    cols = math.prod(s for d, s in enumerate(rhs.shape) if d not in (*rhs_contract, *rhs_batch))
    return 2 * batch * rows * cols * contract


def jaxpr_matmul_flops(jaxpr: Any) -> int:
    """FLOPs of every ``dot_general`` in ``jaxpr``, through nested jaxprs (pjit, custom_vjp,
    scan x length). A ``cond`` counts its most expensive branch."""
    total = 0
    for equation in jaxpr.eqns:
        name = equation.primitive.name
        if name == "dot_general":
            total += _dot_flops(equation)
        elif name == "cond":
            total += max(jaxpr_matmul_flops(b.jaxpr) for b in equation.params["branches"])
        elif name == "scan":
            total += equation.params["length"] * jaxpr_matmul_flops(equation.params["jaxpr"].jaxpr)
        else:
            total += sum(jaxpr_matmul_flops(sub) for sub in _inner_jaxprs(equation))
    return total


def _inner_jaxprs(equation: Any) -> list[Any]:
    """The jaxprs an equation holds in its parameters (pjit, custom_vjp, cond, scan bodies)."""
    found = []
    for value in equation.params.values():
        for sub in value if isinstance(value, tuple | list) else (value,):
            if isinstance(sub, jax_core.ClosedJaxpr):
                found.append(sub.jaxpr)
            elif isinstance(sub, jax_core.Jaxpr):
                found.append(sub)
    return found


def _agent_and_batch(config: td3_module.Config, key: jax.Array):
    """One seed's agent and a sampled critic batch: traced for their shapes only."""
    hparams = td3.default_hyperparams()
    state = td3.init(key, config, hparams)
    stored = replay.sample(state.buffer, jax.random.fold_in(key, 1), config.batch_size)
    return state.agent, CriticBatch.one_step(stored, hparams.gamma)


def _steps(config: td3_module.Config):
    """``(critic(agent, batch, key), actor(agent, batch))``: one seed's two steps, at a constant
    learning rate."""
    hparams = td3.default_hyperparams()
    nets = td3_module.make_networks(config)

    def constant(rate):  # the learning-rate schedule: no decay
        return rate

    def critic(agent, batch, key):
        return td3_module.critic_step(agent, batch, key, hparams, nets, constant)

    def actor(agent, batch):
        return td3_module.actor_step(agent, batch.obs, hparams, nets, constant)

    return critic, actor


def update_flops(config: td3_module.Config) -> dict[str, float]:
    """Matmul FLOPs of one seed's TD3 update: the critic step (target actor and twin target
    critics forward, twin critics forward and backward), the actor step (actor and first critic
    forward, backward through both; it runs every ``policy_delay`` updates) and their average
    per update."""
    # shapes are all the tracing needs (an eager init would compile each of its ops)
    agent, batch = jax.eval_shape(lambda key: _agent_and_batch(config, key), jax.random.key(0))
    critic, actor = _steps(config)
    critic_flops = jaxpr_matmul_flops(jax.make_jaxpr(critic)(agent, batch, jax.random.key(2)).jaxpr)
    actor_flops = jaxpr_matmul_flops(jax.make_jaxpr(actor)(agent, batch).jaxpr)
    return {
        "critic_step": critic_flops,
        "actor_step": actor_flops,
        "per_update": critic_flops + actor_flops / config.policy_delay,
    }


def update_dots(config: td3_module.Config, seeds: int) -> list[tuple[Any, float]]:
    """Every matrix product of one TD3 update of ``seeds`` seeds vmapped (as the training program
    runs it): ``(dot_general equation, runs per update)``; the actor step's products run every
    ``policy_delay`` updates."""
    agents, batch = jax.eval_shape(
        jax.vmap(lambda key: _agent_and_batch(config, key)),
        jax.random.split(jax.random.key(0), seeds),
    )
    critic, actor = _steps(config)
    keys = jax.random.split(jax.random.key(2), seeds)
    traced = [
        (jax.make_jaxpr(jax.vmap(critic))(agents, batch, keys), 1.0),
        (jax.make_jaxpr(jax.vmap(actor))(agents, batch), 1.0 / config.policy_delay),
    ]
    return [(eqn, weight) for jaxpr, weight in traced for eqn in _dot_equations(jaxpr.jaxpr)]


def _dot_equations(jaxpr: Any) -> list[Any]:
    """Every ``dot_general`` equation of ``jaxpr``, nested ones included, once each."""
    found = []
    for equation in jaxpr.eqns:
        if equation.primitive.name == "dot_general":
            found.append(equation)
        for sub in _inner_jaxprs(equation):
            found += _dot_equations(sub)
    return found


def dots_program(
    config: Any,
    seeds: int,
    updates: int,
    devices: int = 1,
    dots_of: Callable[[Any, int], list[tuple[Any, float]]] = update_dots,
) -> tuple[Callable, float]:
    """The update's matrix products alone, at their exact shapes and layouts, ``updates`` times
    in one ``lax.scan``: the rate the training loop would reach if everything but its matmuls
    were free (its roofline on this CPU). On several devices each runs the products of its share
    of the seeds (padded to equal shares, as the training program lays them out) independently.
    ``dots_of(config, seeds)`` lists the update's products (TD3's by default; SAC's:
    ``bench.sac_programs.update_dots``). Returns the call and the FLOPs per call of the
    ``seeds`` seeds (padding left out)."""
    per_device = -(-seeds // devices)
    dots = dots_of(config, per_device)
    key = jax.random.key(3)
    operands = []
    for index, (equation, _) in enumerate(dots):
        lhs, rhs = (v.aval for v in equation.invars)
        pair = jax.random.split(jax.random.fold_in(key, index))
        operands.append(
            (
                jax.random.normal(pair[0], lhs.shape, lhs.dtype),
                jax.random.normal(pair[1], rhs.shape, rhs.dtype),
            )
        )
    # An actor-step product counts 1 / policy_delay: run it in that share of the iterations.
    period = config.policy_delay

    def body(total, index):
        for (equation, weight), (lhs, rhs) in zip(dots, operands, strict=True):
            dimensions = equation.params["dimension_numbers"]

            # The carry enters every product, so none is hoisted out of the loop.
            def product(total, lhs=lhs, rhs=rhs, dimensions=dimensions):
                out = jax.lax.dot_general(lhs + total, rhs, dimensions)
                return jnp.ravel(out)[0] * 1e-30

            if weight < 1.0:
                due = index % period == 0
                total = total + jax.lax.cond(due, product, lambda total: 0.0 * total, total)
            else:
                total = total + product(total)
        return total, None

    def loop(start):  # start: [1] on each device
        return jax.lax.scan(body, start[0], jnp.arange(updates))[0][None]

    mesh = Mesh(np.array(jax.devices()[:devices]), ("d",))
    program = jax.jit(
        jax.shard_map(loop, mesh=mesh, in_specs=PartitionSpec("d"), out_specs=PartitionSpec("d"))
    )
    start = jax.device_put(
        jnp.zeros((devices,), jnp.float32), jax.NamedSharding(mesh, PartitionSpec("d"))
    )
    per_seed = sum(weight * _dot_flops(eqn) for eqn, weight in dots) / per_device
    return (lambda: program(start).block_until_ready()), updates * seeds * per_seed


# ---- programs -----------------------------------------------------------------------------------
def matmul_program(devices: int) -> tuple[Callable[[], Any], float]:
    """A chain of float32 ``MATMUL_SIZE``-square matmuls on each of ``devices`` devices (one
    independent chain per device), and its FLOPs per call."""
    n = MATMUL_SIZE
    mesh = Mesh(np.array(jax.devices()[:devices]), ("d",))
    x = jax.device_put(
        jax.random.normal(jax.random.key(0), (devices * n, n), jnp.float32) / n**0.5,
        jax.NamedSharding(mesh, PartitionSpec("d")),
    )
    w = jax.random.normal(jax.random.key(1), (n, n), jnp.float32) / n**0.5

    def chain(x, w):
        return jax.lax.fori_loop(0, MATMUL_CHAIN, lambda _, x: x @ w, x)

    specs = {"in_specs": (PartitionSpec("d"), PartitionSpec()), "out_specs": PartitionSpec("d")}
    program = jax.jit(jax.shard_map(chain, mesh=mesh, **specs))
    return (lambda: program(x, w).block_until_ready()), 2.0 * devices * MATMUL_CHAIN * n**3


def filled_buffers(config: td3_module.Config, seeds: int, capacity: int) -> Any:
    """``[seeds]`` replay buffers full of random transitions (the update's cost does not depend
    on what the data is, only that sampling reads all of it)."""
    hparams = td3.default_hyperparams()
    config = config.__class__(**{**config.to_dict(), "buffer_size": capacity})
    states = jax.vmap(lambda key: td3.init(key, config, hparams))(
        jax.random.split(jax.random.key(0), seeds)
    )
    buffers = states.buffer
    data = jax.tree.map(
        lambda x: jax.random.normal(jax.random.key(1), x.shape).astype(x.dtype), buffers.data
    )
    full = jnp.full((seeds,), buffers.rows, jnp.int32)
    # Targets start as the online parameters' very arrays; copies can be donated separately.
    agents = jax.tree.map(jnp.copy, states.agent)
    return agents, buffers.replace(data=data, rows_filled=full)


def update_program(
    config: td3_module.Config, seeds: int, devices: int, updates: int, capacity: int = 100_000
) -> Callable[[], Any]:
    """``updates`` TD3 updates of ``seeds`` seeds under one ``lax.scan``: ``vmap`` over seeds
    (every layer of every seed one batched matmul), split over ``devices`` with ``shard_map``
    (seeds padded to a multiple of ``devices``; the padding is wasted work, not counted). The
    update index stays unbatched, so the delayed actor step is a real branch."""
    padded = -(-seeds // devices) * devices
    hparams = td3.default_hyperparams()
    agents, buffers = filled_buffers(config, padded, capacity)
    keys = jax.random.split(jax.random.key(2), padded)

    def run(agents, buffers, keys):
        def one(carry, index):
            agents, buffers = carry
            step_keys = jax.vmap(lambda key: jax.random.fold_in(key, index))(keys)
            agents, buffers, metrics = jax.vmap(
                lambda a, b, k: td3_module.update(a, b, k, config, hparams, index)
            )(agents, buffers, step_keys)
            return (agents, buffers), metrics["critic_loss"]

        (agents, buffers), losses = jax.lax.scan(one, (agents, buffers), jnp.arange(updates))
        return agents, losses

    if devices > 1:
        mesh = Mesh(np.array(jax.devices()[:devices]), ("seeds",))
        spec = PartitionSpec("seeds")
        # check_vma=False: each device's seeds are an independent program (as in parallel.Program)
        run = jax.shard_map(
            run,
            mesh=mesh,
            in_specs=spec,
            out_specs=(spec, PartitionSpec(None, "seeds")),
            check_vma=False,
        )
    # Donating the parameters lets XLA update them (and Adam's moments) in place.
    program = jax.jit(run, donate_argnums=0)
    holder = {"agents": agents}

    def call() -> None:
        holder["agents"], losses = program(holder["agents"], buffers, keys)
        losses.block_until_ready()

    return call


def best_seconds(call: Callable[[], Any], repeats: int, min_time: float = 0.5) -> float:
    """Fastest of ``repeats`` timings, each the mean over calls lasting at least ``min_time``."""
    best = math.inf
    for _ in range(repeats):
        calls, start = 0, time.perf_counter()
        while (elapsed := time.perf_counter() - start) < min_time or calls == 0:
            call()
            calls += 1
        best = min(best, elapsed / calls)
    return best


def load() -> float:
    return os.getloadavg()[0]
