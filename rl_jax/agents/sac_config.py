"""SAC's settings and state: the static ``Config``, the ``Hyperparams`` a sweep varies and the
``Agent`` (parameters, targets, optimizer states). Apart from ``sac`` so that its lower modules
(``sac_networks``, ``sac_losses``, ``sac_update``) can import and type them."""

from __future__ import annotations

import dataclasses

import jax
import optax
from flax import struct

from rl_jax.training import networks, params
from rl_jax.training.networks import Params
from rl_jax.training.normalization import RunningStats
from rl_jax.training.offpolicy import OffPolicyConfig
from rl_jax.training.params import Scalar


@dataclasses.dataclass(frozen=True, kw_only=True)
class Config(OffPolicyConfig):
    """Static settings of SAC (the loop's are in ``OffPolicyConfig``). Defaults: the paper's
    (Table 1: 256 x 256 ReLU networks, batch 256, one update per env step, 10^6 replay)."""

    # env steps (all envs) of uniformly random actions before learning: 10 episodes of 1,000
    # steps, as the authors' own code (softlearning's development variants) starts its runs
    learning_starts: int = 10_000
    actor_hidden: tuple[int, ...] = (256, 256)  # hidden layer widths of the actor
    critic_hidden: tuple[int, ...] = (256, 256)  # hidden layer widths of each critic
    num_critics: int = 2  # critics; the target and the actor take their min
    # critic updates per actor and temperature update (CrossQ: 3; the paper: 1)
    policy_delay: int = 1
    network_init: str = "fan_in_uniform"  # see rl_jax.training.networks
    compute_dtype: str = "float32"  # matmul dtype ("bfloat16" trades precision for speed)
    # Rewards summed before bootstrapping (windows of n_step steps of one env, cut at an
    # episode's end; the steps inside a window add no entropy bonus). 1: the paper's targets.
    n_step: int = 1
    actor_activation: str = "relu"  # hidden nonlinearity of the actor: relu, tanh or elu
    critic_activation: str = "relu"  # of the critics
    # "layer": a LayerNorm between each hidden linear layer of the critics and its
    # nonlinearity (RLPD, BRO). "batch_renorm" (CrossQ): batch renormalisation on the critics'
    # input and after each hidden nonlinearity, training mode in the critic update, evaluation
    # mode (running statistics) for the actor's loss and the targets. "none": the paper's.
    critic_norm: str = "none"
    # the actor's: "none", "layer" or "batch_renorm" (CrossQ's code: training mode in the
    # actor update, running statistics when acting and for the bootstrap actions)
    actor_norm: str = "none"
    # batch_renorm: updates of plain batch norm (no r/d corrections) while the running
    # statistics settle (CrossQ's implementation: 100,000)
    renorm_warmup: int = 100_000
    # False (CrossQ): no target critics: the online critics see the batch's (s, a) and (s', a')
    # in one forward pass, so that batch renormalisation's statistics cover both
    target_networks: bool = True
    # Adam's first-moment decay for actor and critics (CrossQ: 0.5; the temperature keeps 0.9)
    adam_b1: float = 0.9
    # "simba" (SimBa): observations standardised by running statistics, then a linear layer,
    # one pre-LayerNorm residual block per entry of actor_hidden / critic_hidden (all one
    # width), a LayerNorm and the output layer. "mlp": the paper's MLPs.
    network: str = "mlp"
    # observations standardised by running statistics for the MLPs too (SimBa always does)
    normalize_obs: bool = False
    # False: the temperature stays at initial_alpha (the first SAC paper's fixed alpha)
    learn_temperature: bool = True
    log_std_min: float = -20.0  # lower clip of the actor's log-std (softlearning's, CrossQ's)
    log_std_max: float = 2.0  # upper clip of the actor's log-std

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.num_critics < 1 or self.policy_delay < 1 or self.n_step < 1:
            raise ValueError("num_critics, policy_delay and n_step must be >= 1")
        if self.network_init not in networks.INITS:
            raise ValueError(f"network_init must be one of {networks.INITS}")
        for name in ("actor_activation", "critic_activation"):
            if getattr(self, name) not in networks.ACTIVATIONS:
                raise ValueError(f"{name} must be one of {tuple(networks.ACTIVATIONS)}")
        for name in ("critic_norm", "actor_norm"):
            if getattr(self, name) not in networks.NORMS:
                raise ValueError(f"{name} must be one of {networks.NORMS}")
        hidden = {"actor_hidden": self.actor_hidden, "critic_hidden": self.critic_hidden}
        networks.check_architecture(self.network, hidden, (self.critic_norm, self.actor_norm))
        if self.log_std_min >= self.log_std_max:
            raise ValueError("log_std_min must be below log_std_max")

    @property
    def standardizes_obs(self) -> bool:
        """Whether the networks read observations standardised by running statistics."""
        return self.normalize_obs or self.network == "simba"


@struct.dataclass
class Hyperparams(params.HyperparamsMethods):
    """What a sweep may vary without recompiling. Defaults: the paper's (Table 1)."""

    actor_lr: Scalar = 3e-4  # Adam step size of the actor
    critic_lr: Scalar = 3e-4  # Adam step size of the critics
    alpha_lr: Scalar = 3e-4  # Adam step size of log(alpha)
    gamma: Scalar = 0.99  # discount
    tau: Scalar = 0.005  # Polyak step of the target critics after every critic update
    initial_alpha: Scalar = 1.0  # the temperature at the start (throughout if not learned)
    # the entropy the temperature holds the policy at, per action dim (the paper: -1, i.e. -|A|)
    target_entropy_per_dim: Scalar = -1.0


@struct.dataclass
class Agent:
    """Parameters, targets and optimizer states; None where an option is off."""

    actor: Params  # actor parameters
    critics: Params  # critic parameters, leaves [num_critics, ...]
    target_critics: Params | None  # Polyak copies (None without target networks)
    log_alpha: jax.Array  # [] float32, log of the temperature
    actor_opt: optax.OptState  # optax inject_hyperparams(adam) states: they hold the rates in use
    critic_opt: optax.OptState
    alpha_opt: optax.OptState
    actor_stats: Params | None = None  # actor_norm "batch_renorm": the actor's running statistics
    critic_stats: Params | None = (
        None  # critic_norm "batch_renorm": the critics' [num_critics, ...]
    )
    # simba / normalize_obs: the running statistics of the observations acted on
    obs_stats: RunningStats | None = None
