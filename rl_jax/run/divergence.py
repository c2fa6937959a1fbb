"""Stopping a run whose parameters, evaluation or losses stop being finite, before its state is
saved, with one line naming the runs and the likely cause."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from rl_jax.errors import RunError
from rl_jax.run.best import policy_fields, policy_part
from rl_jax.run.spec import RunSpec
from rl_jax.training.algorithm import ChunkMetrics, TrainState

if TYPE_CHECKING:
    from rl_jax.run.runner import Session


class DivergenceError(RunError):
    """A run's parameters or evaluation became non-finite: the run stopped before saving it."""


@jax.jit
def _all_finite(tree: object) -> jax.Array:
    """``[H, S]``: whether every float leaf of each run of ``tree`` is finite."""
    flags = [
        jnp.all(jnp.isfinite(leaf), axis=tuple(range(2, leaf.ndim)))
        for leaf in jax.tree.leaves(tree)
        if jnp.issubdtype(leaf.dtype, jnp.floating)
    ]
    return jnp.all(jnp.stack(flags), axis=0) if flags else jnp.bool_(True)


def finite_runs(state: TrainState, spec: RunSpec) -> jax.Array:
    """Per run (padded ``[H, S]``), whether its policy part (or whole state) is finite."""
    fields = policy_fields(spec.algorithm, state)
    return _all_finite(policy_part(state, fields) if fields else state)


def check_finite(session: Session, metrics: ChunkMetrics, finite_state: np.ndarray) -> None:
    """Stop the run, before its state is saved, when a run's parameters or eval return are no
    longer finite, or a loss overflowed to infinity: one line names the runs, the step and the
    likely cause. (A NaN loss alone is no sign: learners report NaN for "no update here", e.g.
    while warming up; a NaN that came from diverging reaches the parameters.)"""
    spec = session.spec
    params_ok = np.asarray(finite_state, bool)
    eval_ok = np.isfinite(np.asarray(metrics.eval_return, dtype=np.float64))
    losses_ok = np.ones_like(eval_ok)
    for value in metrics.extra.values():
        value = np.asarray(value)
        if value.dtype.kind == "f" and value.shape == losses_ok.shape:
            losses_ok &= ~np.isinf(value)
    finite = params_ok & eval_ok & losses_ok
    if finite.all():
        return
    bad = np.argwhere(~finite)
    runs = ", ".join(
        f"seed {spec.base_seed + s}" + (f" of config {h}" if len(spec.hparams) > 1 else "")
        for h, s in bad
    )
    what = [
        name
        for name, ok in (
            ("parameters", params_ok),
            ("eval return", eval_ok),
            ("losses", losses_ok),
        )
        if not ok[~finite].all()
    ]
    rates = sorted(
        {
            f"--{name.replace('_', '-')} {float(np.asarray(getattr(spec.hparams[h], name))):g}"
            for h, _ in bad
            for name in _rate_fields(spec.hparams[h])
        }
    )
    clipping = any(
        f.name == "max_grad_norm" for h, _ in bad for f in dataclasses.fields(spec.hparams[h])
    )
    kept = (
        f"the last finite checkpoint (step {session.saved_step:,}) is kept"
        if session.saved_step is not None
        else "no checkpoint had been written yet"
    )
    raise DivergenceError(
        f"training diverged at step {session.step:,}: {runs} got non-finite "
        f"{' and '.join(what)}; {kept} and the run stops here. Likely cause: a learning rate "
        f"too high for this problem ({', '.join(rates) or 'see config.json'}) or exploding "
        "gradients; try a lower rate"
        + (" or a lower --max-grad-norm (gradient clipping)" if clipping else "")
    )


def _rate_fields(hparams: object) -> list[str]:
    return [
        f.name
        for f in dataclasses.fields(hparams)
        if f.name == "lr" or f.name.endswith(("_lr", "learning_rate"))
    ]
