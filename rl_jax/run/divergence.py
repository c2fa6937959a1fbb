"""Stopping a run whose parameters, evaluation or losses stop being finite, before its state is
saved, with one line naming the runs and the likely cause."""

from __future__ import annotations

from typing import Protocol

import jax
import jax.numpy as jnp
import numpy as np

from rl_jax.errors import RunError
from rl_jax.run.best import policy_fields, policy_part
from rl_jax.run.spec import RunSpec
from rl_jax.training import params
from rl_jax.training.algorithm import ChunkMetrics, TrainState


class DivergenceError(RunError):
    """A run's parameters or evaluation became non-finite: the run stopped before saving it."""


class RunSoFar(Protocol):
    """What the check reads of a run in progress (``rl_jax.run.runner.Session`` is one)."""

    @property
    def spec(self) -> RunSpec:
        """The run's spec: algorithm, seeds and hyperparameter sets."""
        ...

    @property
    def step(self) -> int:
        """Env steps per seed reached."""
        ...

    @property
    def saved_step(self) -> int | None:
        """The step of the latest checkpoint (None: none yet)."""
        ...


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


def check_finite(
    session: RunSoFar, metrics: ChunkMetrics, finite_state: np.ndarray | jax.Array
) -> None:
    """Stop the run, before its state is saved, when a run's parameters or eval return are no
    longer finite, or a loss overflowed to infinity: one line names the runs, the step and the
    likely cause. (A NaN loss alone is no sign: learners report NaN for "no update here", e.g.
    while warming up; a NaN that came from diverging reaches the parameters.)"""
    spec = session.spec
    params_ok = np.asarray(finite_state, bool)
    eval_ok = np.isfinite(np.asarray(metrics.eval_return, dtype=np.float64))
    losses_ok = np.ones_like(eval_ok)
    for value in metrics.extra.values():
        loss = np.asarray(value)
        if loss.dtype.kind == "f" and loss.shape == losses_ok.shape:
            losses_ok &= ~np.isinf(loss)
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
    diverged = [params.dataclass_to_dict(spec.hparams[h]) for h in sorted({h for h, _ in bad})]
    rates = sorted(
        {
            f"--{name.replace('_', '-')} {float(np.asarray(value)):g}"
            for values in diverged
            for name, value in values.items()
            if _is_rate(name)
        }
    )
    clipping = any("max_grad_norm" in values for values in diverged)
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


def _is_rate(name: str) -> bool:
    """Whether the hyperparameter ``name`` is a learning rate (``lr``, ``*_lr``,
    ``*learning_rate``)."""
    return name == "lr" or name.endswith(("_lr", "learning_rate"))
