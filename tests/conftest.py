"""Test-wide JAX settings: fail on silent rank promotion, share the compilation cache."""

import jax

from rl_jax.jax_setup import configure

configure()
jax.config.update("jax_numpy_rank_promotion", "raise")
