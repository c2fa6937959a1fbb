"""Actor and critic networks (flax linen), and stacked ensembles of them.

Why linen: its modules are stateless descriptions and parameters are plain pytrees, so a train
state is just arrays (jit, vmap over seeds, ``lax.scan`` carries and orbax checkpoints take it as
is), several critics are one stacked pytree made by ``jax.vmap(module.init)``, and target networks
are simply a second pytree. nnx's mutable objects would need split/merge at every one of those
boundaries.

Initialisation, chosen on purpose:

* ``"fan_in_uniform"`` (default): weights and biases ~ U(-1/sqrt(fan_in), 1/sqrt(fan_in)), the
  PyTorch ``nn.Linear`` default that the TD3 reference implementation (and CleanRL) trained with;
  the published TD3/DDPG hyperparameters were tuned with it, so they carry over unchanged.
* ``"orthogonal"``: orthogonal weights (gain sqrt(2) for ReLU layers, ``output_gain`` for the last
  layer) and zero biases, as on-policy recipes use; a setting for experiments.

Normalisation inside the MLPs (``NORMS``), for critics that stay stable at high update rates:
``"layer"`` puts a LayerNorm between each hidden linear layer and its nonlinearity (as RLPD and
BRO place it: the nonlinearity sees normalised pre-activations; the output layer stays linear).
``"batch_renorm"`` places ``batch_renorm.BatchRenorm`` as CrossQ does: on the input and after each
hidden nonlinearity; such a network takes ``train`` and keeps statistics in ``batch_stats``.

SimBa (Lee et al. 2025, ``Simba``): a linear layer to width ``w``, then residual blocks that each
add ``dense(w) . relu . dense(4w) . LayerNorm`` of their input to it (pre-LN: the skip path is the
identity, so depth does not bend the network away from a simple function), a final LayerNorm and
the output layer. SimBa also standardises the observations by running statistics
(``rl_jax.training.normalization``); the learner does that before the network.

State-action embeddings (TD7's SALE, ``StateActionEncoder``): actor and critic take learned
embeddings beside their raw inputs. The raw input first goes through one linear layer scaled by
``avg_l1_norm`` (so neither part dominates the concatenation by scale), then the embeddings are
appended and the usual MLP follows.

Every network takes its hidden layers as one ``Layers`` spec (widths, nonlinearity,
initialisation, normalisation, architecture, compute dtype), checked once where it is made.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any, Literal, TypeAlias, get_args

import flax.linen as nn
import jax
import jax.numpy as jnp
from jax.typing import DTypeLike

from rl_jax.training.batch_renorm import BatchRenorm
from rl_jax.training.conv import INITS, ConvTorso, uniform_init

#: A network's variables as flax keeps them (``{"params": ..., "batch_stats": ...}``).
Params: TypeAlias = Mapping[str, Any]

#: weight initialisation schemes (see the module docstring)
Initializer: TypeAlias = Literal["fan_in_uniform", "orthogonal"]
#: hidden-layer nonlinearities (the keys of ``ACTIVATIONS``)
Activation: TypeAlias = Literal["relu", "tanh", "elu"]
#: normalisation of an MLP's hidden layers (see the module docstring)
Norm: TypeAlias = Literal["none", "layer", "batch_renorm"]
#: the torso of actor and critic: plain MLP or SimBa's residual blocks
Architecture: TypeAlias = Literal["mlp", "simba"]
#: a Gaussian policy's std: a "state"-dependent head or a learned, state-free "param"
StdMode: TypeAlias = Literal["state", "param"]

#: hidden-layer nonlinearities, with the orthogonal gain that keeps activations' scale
ACTIVATIONS: dict[Activation, tuple[Callable[[jax.Array], jax.Array], float]] = {
    "relu": (nn.relu, 2.0**0.5),
    "tanh": (nn.tanh, 5.0 / 3.0),
    "elu": (nn.elu, 2.0**0.5),
}
NORMS: tuple[Norm, ...] = get_args(Norm)
ARCHITECTURES: tuple[Architecture, ...] = get_args(Architecture)


@dataclasses.dataclass(frozen=True)
class Layers:
    """A network's hidden layers: ``hidden`` widths, each ``activation`` after a linear layer
    initialised by ``initializer``, normalised by ``norm`` (batch renormalisation warming up over
    ``renorm_warmup`` updates), as an ``architecture`` ("mlp", or SimBa's residual blocks), with
    matmuls in ``dtype`` (parameters stay float32). Frozen and hashable, like the modules that hold
    it; an unknown option is a ``ValueError`` here, where the spec is made."""

    hidden: tuple[int, ...]
    activation: Activation = "relu"
    initializer: Initializer = "fan_in_uniform"
    norm: Norm = "none"
    architecture: Architecture = "mlp"
    dtype: DTypeLike = jnp.float32
    renorm_warmup: int = 100_000

    def __post_init__(self) -> None:
        if self.initializer not in INITS:
            raise ValueError(f"unknown initializer {self.initializer!r}; choose one of {INITS}")
        if self.activation not in ACTIVATIONS:
            raise ValueError(
                f"unknown activation {self.activation!r}; choose one of {list(ACTIVATIONS)}"
            )
        if self.norm not in NORMS:
            raise ValueError(f"unknown norm {self.norm!r}; choose one of {NORMS}")
        if self.architecture not in ARCHITECTURES:
            raise ValueError(
                f"unknown architecture {self.architecture!r}; choose one of {ARCHITECTURES}"
            )
        if self.architecture == "simba":
            check_architecture("simba", {"hidden": self.hidden}, (self.norm,))


def check_architecture(
    network: str, hidden: Mapping[str, tuple[int, ...]], norms: tuple[str, ...]
) -> None:
    """``ValueError`` unless ``network`` is one of ``ARCHITECTURES``. SimBa's residual blocks
    keep one width, so each of ``hidden`` (setting name -> hidden widths) must have one, and
    bring their own LayerNorms, so each of ``norms`` must be "none"."""
    if network not in ARCHITECTURES:
        raise ValueError(f"network must be one of {ARCHITECTURES}")
    if network == "simba":
        for name, widths in hidden.items():
            if not widths or len(set(widths)) != 1:
                raise ValueError(f"network='simba' needs {name} of one width (w, w, ...)")
        if any(norm != "none" for norm in norms):
            raise ValueError("network='simba' has its own LayerNorms: leave the norms 'none'")


def dense(
    features: int, fan_in: int, initializer: Initializer, gain: float, dtype: DTypeLike
) -> nn.Dense:
    """A linear layer initialised by the named scheme (``gain`` only matters for orthogonal)."""
    if initializer == "fan_in_uniform":
        bound = 1.0 / fan_in**0.5
        kernel_init, bias_init = uniform_init(bound), uniform_init(bound)
    elif initializer == "orthogonal":
        kernel_init, bias_init = nn.initializers.orthogonal(gain), nn.initializers.zeros
    else:
        raise ValueError(f"unknown initializer {initializer!r}; choose one of {INITS}")
    return nn.Dense(features, dtype=dtype, kernel_init=kernel_init, bias_init=bias_init)


def _float32(x: jax.Array) -> jax.Array:
    # Low-precision compute (bfloat16) still hands float32 to the losses.
    return x.astype(jnp.promote_types(x.dtype, jnp.float32))


def _activation(name: Activation) -> tuple[Callable[[jax.Array], jax.Array], float]:
    if name not in ACTIVATIONS:
        raise ValueError(f"unknown activation {name!r}; choose one of {list(ACTIVATIONS)}")
    return ACTIVATIONS[name]


class Torso(nn.Module):
    """Hidden layers only: ``[..., in] -> [..., hidden[-1]]`` (the input itself if none).
    ``norm="layer"``: dense -> LayerNorm -> nonlinearity in each layer, as ``MLP``'s. Plain
    layers: the spec's norm is "none" or "layer" and its architecture "mlp"."""

    layers: Layers

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        spec = self.layers
        if spec.norm not in ("none", "layer"):
            raise ValueError(f"a Torso's norm is 'none' or 'layer', got {spec.norm!r}")
        if spec.architecture != "mlp":
            raise ValueError(f"a Torso's architecture is 'mlp', got {spec.architecture!r}")
        function, gain = _activation(spec.activation)
        for width in spec.hidden:
            x = dense(width, x.shape[-1], spec.initializer, gain, spec.dtype)(x)
            if spec.norm == "layer":
                x = nn.LayerNorm(dtype=spec.dtype)(x)
            x = function(x)
        return x


class MLP(nn.Module):
    """The hidden ``layers`` (ReLU by default), then a linear output of ``outputs`` (orthogonal
    init: at ``output_gain``). Parameters float32; ``layers.dtype`` is the compute dtype.
    ``norm="layer"``: dense -> LayerNorm -> nonlinearity in each hidden layer;
    ``"batch_renorm"``: BatchRenorm on the input and after each nonlinearity (``train`` picks its
    mode, ``layers.renorm_warmup`` its warm-up). The spec's architecture is not read here:
    ``MLP`` and ``Simba`` are the two architectures."""

    layers: Layers
    outputs: int
    output_gain: float = 1.0

    @nn.compact
    def __call__(self, x: jax.Array, train: bool = False) -> jax.Array:
        # The layers sit directly in this module (not in a Torso): parameter names stay
        # Dense_0 .. Dense_k, as saved checkpoints have them (norm layers add their own).
        spec = self.layers
        function, gain = _activation(spec.activation)
        renorm = spec.norm == "batch_renorm"
        if renorm:
            x = BatchRenorm(spec.renorm_warmup, spec.dtype)(x, train)
        for width in spec.hidden:
            x = dense(width, x.shape[-1], spec.initializer, gain, spec.dtype)(x)
            if spec.norm == "layer":
                x = nn.LayerNorm(dtype=spec.dtype)(x)
            x = function(x)
            if renorm:
                x = BatchRenorm(spec.renorm_warmup, spec.dtype)(x, train)
        x = dense(self.outputs, x.shape[-1], spec.initializer, self.output_gain, spec.dtype)(x)
        return _float32(x)


class SimbaBlock(nn.Module):
    """SimBa's pre-LayerNorm residual block: ``x + dense(w)(act(dense(4w)(LN(x))))``."""

    width: int
    initializer: Initializer = "fan_in_uniform"
    dtype: DTypeLike = jnp.float32
    activation: Activation = "relu"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        function, gain = _activation(self.activation)
        h = nn.LayerNorm(dtype=self.dtype)(x)
        h = function(dense(4 * self.width, self.width, self.initializer, gain, self.dtype)(h))
        return x + dense(self.width, 4 * self.width, self.initializer, 1.0, self.dtype)(h)


class Simba(nn.Module):
    """SimBa's network in ``MLP``'s place: ``dense(w)``, one ``SimbaBlock`` per entry of
    ``layers.hidden`` (all entries equal ``w``), LayerNorm, linear output of ``outputs``. The
    blocks bring their own LayerNorms: the spec's norm is not read."""

    layers: Layers
    outputs: int
    output_gain: float = 1.0

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        spec = self.layers
        if not spec.hidden or len(set(spec.hidden)) != 1:
            raise ValueError(f"SimBa blocks share one width, got hidden {spec.hidden}")
        width = spec.hidden[0]
        x = dense(width, x.shape[-1], spec.initializer, 1.0, spec.dtype)(x)
        for _ in spec.hidden:
            block = SimbaBlock(
                width, initializer=spec.initializer, dtype=spec.dtype, activation=spec.activation
            )
            x = block(x)
        x = nn.LayerNorm(dtype=spec.dtype)(x)
        return _float32(
            dense(self.outputs, width, spec.initializer, self.output_gain, spec.dtype)(x)
        )


def torso_and_head(layers: Layers, outputs: int, output_gain: float) -> MLP | Simba:
    """The hidden ``layers`` and a linear output of ``outputs``: an ``MLP``, or a ``Simba`` when
    ``layers.architecture`` says so. Only the ``MLP`` takes ``train``."""
    if layers.architecture == "simba":
        return Simba(layers=layers, outputs=outputs, output_gain=output_gain)
    return MLP(layers=layers, outputs=outputs, output_gain=output_gain)


def avg_l1_norm(x: jax.Array, eps: float = 1e-8) -> jax.Array:
    """``x / mean(|x|)`` over the last axis (TD7's AvgL1Norm): features of mean magnitude 1."""
    return x / jnp.maximum(jnp.mean(jnp.abs(x), axis=-1, keepdims=True), eps)


class StateActionEncoder(nn.Module):
    """TD7's SALE encoders: ``embed_state`` ``f(s) = avg_l1_norm(MLP(s))`` and ``embed_pair``
    ``g(z_s, a) = MLP([z_s, a])``, both MLPs of the hidden ``layers`` (TD7's nonlinearity is
    elu) and ``embedding_dim`` outputs; ``g(f(s), a)`` learns to predict ``f(s')``.
    ``__call__`` gives ``(z_s, z_sa)``."""

    layers: Layers
    embedding_dim: int

    def setup(self) -> None:
        self.state_mlp = MLP(layers=self.layers, outputs=self.embedding_dim)
        self.pair_mlp = MLP(layers=self.layers, outputs=self.embedding_dim)

    def embed_state(self, obs: jax.Array) -> jax.Array:
        return avg_l1_norm(self.state_mlp(obs))

    def embed_pair(self, zs: jax.Array, action: jax.Array) -> jax.Array:
        return self.pair_mlp(jnp.concatenate([zs, action], axis=-1))

    def __call__(self, obs: jax.Array, action: jax.Array) -> tuple[jax.Array, jax.Array]:
        zs = self.embed_state(obs)
        return zs, self.embed_pair(zs, action)


def _with_embeddings(layers: Layers, x: jax.Array, embeddings: jax.Array | None) -> jax.Array:
    """``[avg_l1_norm(dense(x)), embeddings]`` (a ``Dense_0`` of the first hidden width in the
    calling module), or ``x`` unchanged without embeddings."""
    if embeddings is None:
        return x
    width = layers.hidden[0] if layers.hidden else x.shape[-1]
    layer = dense(width, x.shape[-1], layers.initializer, 1.0, layers.dtype)
    return jnp.concatenate([avg_l1_norm(layer(x)), embeddings.astype(layers.dtype)], axis=-1)


class Actor(nn.Module):
    """Deterministic policy ``obs [..., obs_dim] -> action [..., action_dim]`` inside the bounds:
    a tanh squashes the output of the hidden ``layers`` (an ``MLP`` or ``Simba``) and an affine
    map stretches [-1, 1] onto [low, high]."""

    layers: Layers
    action_low: tuple[float, ...]
    action_high: tuple[float, ...]

    @nn.compact
    def __call__(self, obs: jax.Array, zs: jax.Array | None = None) -> jax.Array:
        """``zs``: the SALE state embedding, which joins the observation's features."""
        x = _with_embeddings(self.layers, obs, zs)
        raw = torso_and_head(self.layers, len(self.action_low), 0.01)(x)
        # Bounds get explicit leading axes: no silent rank promotion against a batch.
        bounds_shape = (1,) * (raw.ndim - 1) + (len(self.action_low),)
        low = jnp.reshape(jnp.asarray(self.action_low, raw.dtype), bounds_shape)
        high = jnp.reshape(jnp.asarray(self.action_high, raw.dtype), bounds_shape)
        return low + (jnp.tanh(raw) + 1.0) * 0.5 * (high - low)


class Critic(nn.Module):
    """Action value ``(obs [..., obs_dim], action [..., action_dim]) -> q [...]`` through the
    hidden ``layers`` (an ``MLP`` or ``Simba``); the action enters at the first layer together
    with the observation (as in TD3, unlike the original DDPG).
    """

    layers: Layers

    @nn.compact
    def __call__(
        self,
        obs: jax.Array,
        action: jax.Array,
        embeddings: jax.Array | None = None,
        train: bool = False,
    ) -> jax.Array:
        """``embeddings``: SALE's ``[z_sa, z_s]``, which join the state-action features;
        ``train``: batch renormalisation's mode."""
        x = _with_embeddings(self.layers, jnp.concatenate([obs, action], axis=-1), embeddings)
        body = torso_and_head(self.layers, 1, 1.0)
        if isinstance(body, MLP) and self.layers.norm == "batch_renorm":
            return body(x, train)[..., 0]
        return body(x)[..., 0]


class QNetwork(nn.Module):
    """Action values of a discrete action space: ``obs [..., obs_dim] -> q [..., num_actions]``
    (or ``obs [..., H, W, C]`` through a ``ConvTorso`` when ``conv_layers`` is set), through a
    ``Torso`` of the hidden ``layers``.

    ``dueling`` (Wang et al. 2016): the torso feeds a state-value head ``v`` and an advantage head
    ``a``, combined as ``q = v + a - mean(a)`` (the mean makes the split identifiable).
    ``norm="layer"``: LayerNorm before each hidden nonlinearity (as PQN's Q-network)."""

    layers: Layers
    num_actions: int
    dueling: bool = False
    conv_layers: tuple[int, ...] = ()  # set: obs are images [..., H, W, C], see ConvTorso
    conv_rows: tuple[int, ...] = ()  # (first, stop): the image rows the ConvTorso sees
    obs_high: float = 255.0  # images' largest value, scaled to 1 by the ConvTorso

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        spec = self.layers
        if self.conv_layers:
            torso = ConvTorso(
                self.conv_layers,
                initializer=spec.initializer,
                dtype=spec.dtype,
                rows=self.conv_rows,
                high=self.obs_high,
            )
            obs = torso(obs)
        x = Torso(layers=spec)(obs)
        head = lambda outputs: dense(outputs, x.shape[-1], spec.initializer, 1.0, spec.dtype)  # noqa: E731
        if not self.dueling:
            return _float32(head(self.num_actions)(x))
        value, advantage = head(1)(x), head(self.num_actions)(x)
        return _float32(value + advantage - jnp.mean(advantage, axis=-1, keepdims=True))


class StochasticPolicy(nn.Module):
    """A policy network for policy-gradient learners: a ``Torso`` of the hidden ``layers`` and
    float32 heads on its features.

    ``num_actions`` set: a categorical policy, ``logits [..., num_actions]``. Otherwise a diagonal
    Gaussian over ``action_dim`` dims: ``mean`` and ``std``. ``std_mode="state"``: a state-dependent
    head, ``std = softplus(raw) + std_floor``; ``"param"``: one learned log-std per action dim,
    independent of the state (initially ``initial_std``), ``std = exp(log_std) + std_floor``. The
    floor keeps the std, and so the log-density, finite. ``value`` adds a state-value head
    ``[...]``: on the policy's features, or on a torso of its own (``layers`` but
    ``value_hidden`` widths) when ``value_hidden`` is given (the value loss then does not shape
    the policy's features). Returns a dict.
    """

    layers: Layers
    action_dim: int = 1
    num_actions: int | None = None
    std_floor: float = 1e-3
    value: bool = False
    std_mode: StdMode = "state"
    initial_std: float = 1.0
    value_hidden: tuple[int, ...] = ()

    @nn.compact
    def __call__(self, obs: jax.Array) -> dict[str, jax.Array]:
        init = self.layers.initializer
        x = Torso(layers=self.layers)(obs)
        head = lambda outputs: dense(outputs, x.shape[-1], init, 0.01, jnp.float32)  # noqa: E731
        if self.num_actions is not None:
            out = {"logits": head(self.num_actions)(x)}
        else:
            out = {"mean": head(self.action_dim)(x), "std": self._std(x, head)}
        if self.value and self.value_hidden:
            value_layers = dataclasses.replace(self.layers, hidden=self.value_hidden)
            features = Torso(layers=value_layers)(obs)
            out["value"] = dense(1, self.value_hidden[-1], init, 1.0, jnp.float32)(features)[..., 0]
        elif self.value:
            out["value"] = head(1)(x)[..., 0]
        return out

    def _std(self, x: jax.Array, head: Callable[[int], nn.Module]) -> jax.Array:
        if self.std_mode == "state":
            return nn.softplus(head(self.action_dim)(x)) + self.std_floor
        if self.std_mode != "param":
            raise ValueError(f"std_mode must be 'state' or 'param', got {self.std_mode!r}")
        start = jnp.log(jnp.float32(self.initial_std))
        log_std = self.param("log_std", lambda _, shape: jnp.full(shape, start), (self.action_dim,))
        return jnp.broadcast_to(jnp.exp(log_std), x.shape[:-1] + (self.action_dim,)) + (
            self.std_floor
        )


def init_stacked(
    module: nn.Module, key: jax.Array, count: int, *example_inputs: jax.Array
) -> Params:
    """Independent parameters for ``count`` copies of ``module`` as one pytree, leaves
    ``[count, ...]`` (the twin critics of TD3 are ``count=2``)."""
    in_axes = (0,) + (None,) * len(example_inputs)
    return jax.vmap(module.init, in_axes=in_axes)(jax.random.split(key, count), *example_inputs)


def apply_stacked(module: nn.Module, params: Params, *inputs: jax.Array) -> jax.Array:
    """Every stacked copy on the same inputs: outputs gain a leading ``[count]`` axis."""
    in_axes = (0,) + (None,) * len(inputs)
    return jax.vmap(module.apply, in_axes=in_axes)(params, *inputs)
