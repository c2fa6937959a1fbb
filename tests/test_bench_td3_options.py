"""``bench.bench_td3_options``' FLOP count of a whole TD3 update, against the count the TD3
benchmark makes step by step (``bench.td3_programs.update_flops``) and against a hand count."""

import jax
import pytest

from bench import td3_programs
from bench.bench_td3_options import update_gflop
from rl_jax.agents.td3 import td3
from rl_jax.agents.td7 import td7

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def _config(learner=td3, **overrides):
    base = {"actor_hidden": (32, 32), "critic_hidden": (32, 32), "batch_size": 16}
    return learner.default_config("rl_jax/HalfCheetah-v5", **{**base, **overrides})


SALE = {"embedding_dim": 8, "embedding_hidden": (32, 32)}


def test_whole_update_count_equals_the_step_by_step_count_for_plain_td3():
    config = _config()
    steps = td3_programs.update_flops(config)
    assert update_gflop(config) * 1e9 == pytest.approx(steps["per_update"], rel=1e-12)


def test_sale_encoder_loss_counts_its_products_by_hand():
    """Half cheetah: 17-d observations, 6-d actions; SALE with 8-d embeddings from 32 x 32
    encoders, batch 16. The loss's gradient: f(s) and g(z_s, a) forward and backward (every
    layer's weight gradient, every input gradient but f's first, whose input is data), and f(s')
    forward only (its target)."""
    import jax.numpy as jnp

    from bench.bench_td3_options import _flops_range
    from rl_jax.agents.actor_critic import CriticBatch
    from rl_jax.agents.td7 import encoder_loss_fn, make_networks

    config = _config(td7, **SALE)
    encoder = make_networks(config)[1]
    batch_size = 16
    obs, action = jnp.zeros((batch_size, 17)), jnp.zeros((batch_size, 6))
    params = encoder.init(jax.random.key(0), obs, action)
    batch = CriticBatch(obs, action, jnp.zeros(batch_size), jnp.ones(batch_size), obs)
    loss = jax.value_and_grad(lambda params, batch: encoder_loss_fn(params, batch, encoder))
    traced = jax.make_jaxpr(loss)(params, batch)

    def dense(n_in, n_out):
        return 2 * batch_size * n_in * n_out

    f_layers = [(17, 32), (32, 32), (32, 8)]
    g_layers = [(8 + 6, 32), (32, 32), (32, 8)]
    forward = sum(dense(*s) for s in f_layers + g_layers)
    backward = forward + forward - dense(17, 32)
    target = sum(dense(*s) for s in f_layers)
    assert _flops_range(traced.jaxpr) == (forward + backward + target,) * 2


def test_td7_costs_more_than_td3():
    """The critics and the actor read the embeddings too: TD7's update costs its encoder step
    plus wider first layers, so more than plain TD3's update."""
    plain = update_gflop(_config())
    sale = update_gflop(_config(td7, **SALE), "td7")
    assert sale > plain
