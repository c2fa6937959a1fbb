"""POPGym's card memory tasks at difficulty Easy, in JAX: RepeatPrevious, RepeatFirst, CountRecall
and Autoencode (Morad et al. 2023, "POPGym: Benchmarking Partially Observable Reinforcement
Learning", and its package ``popgym`` 1.0.7, whose rules these follow step for step).

Each episode deals a shuffled 52-card deck one card a step; the agent sees only the card just
dealt (a suit or a colour) and must act on what it saw earlier. Card ``c`` has popgym's suit
``c % 4``, colour ``c % 2`` and rank ``c // 4``. The state holds the deck in dealing order
(``cards[0]`` is dealt at the reset) and the step count, so a whole episode is fixed at the reset
and ``state_from_vector(cards)`` replays one of popgym's (its ``deck.idx`` reversed: popgym deals
from the end of that array).

popgym observes integers (``Discrete`` or a tuple of them); POPGym's baselines fed them to their
networks one-hot, through RLlib's preprocessor, and so do these envs: a float32 one-hot vector per
integer, concatenated. Rewards are popgym's (each task's total is at most 1 and at least -1 or 0),
every episode ends by termination after a fixed number of steps (popgym never truncates these),
and ``max_episode_steps`` is one step more than that, so that neither our limit nor gymnasium's
``TimeLimit`` ever reports a truncation popgym would not.
"""

from __future__ import annotations

from typing import TypeVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax.envs.core.core import Array, Environment, EnvParams, EnvState, PRNGKey
from rl_jax.envs.core.spaces import Box, Discrete

SUITS = 4
COLORS = 2
DECK_SIZE = 52


def suit_of(card: Array) -> Array:
    """popgym's suit index of a card (``Deck.suits_idx``)."""
    return card % SUITS


def color_of(card: Array) -> Array:
    """popgym's colour index of a card (``Deck.colors_idx``)."""
    return card % COLORS


def _unit_box(size: int) -> Box:
    return Box(np.zeros(size, np.float32), np.ones(size, np.float32), (size,))


def one_hot(index: Array, size: int) -> Array:
    """``[size]`` float32, 1 at ``index``."""
    return jax.nn.one_hot(index, size, dtype=jnp.float32)


@struct.dataclass
class CardState(EnvState):
    """A card task's state: the deck in dealing order; ``time`` cards were dealt after it."""

    cards: Array  # [num_cards] int32, card ids; cards[0] is dealt at the reset


CardStateT = TypeVar("CardStateT", bound=CardState)


class CardTask(Environment[CardStateT, EnvParams]):
    """Base of the card tasks: the pack, the default spaces and the scoring."""

    num_decks = 1
    max_episode_steps = DECK_SIZE

    @property
    def num_cards(self) -> int:
        """Cards in the shuffled pack (52 per deck)."""
        return DECK_SIZE * self.num_decks

    @property
    def default_params(self) -> EnvParams:
        """No dynamic parameters: the rules are fixed by the difficulty."""
        return EnvParams()

    def shuffled(self, key: PRNGKey) -> Array:
        """``[num_cards]`` int32: a uniformly shuffled pack, in dealing order."""
        return jax.random.permutation(key, self.num_cards).astype(jnp.int32)

    def action_space(self, params: EnvParams | None = None) -> Discrete:
        """A suit: popgym's ``Discrete(4)``."""
        return Discrete(SUITS)

    def observation_space(self, params: EnvParams | None = None) -> Box:
        """One-hot suit of the card just dealt."""
        return _unit_box(SUITS)

    def dealt(self, cards: Array, index: Array) -> Array:
        """``cards[index]``, the index clipped into the pack."""
        return cards[jnp.clip(index, 0, self.num_cards - 1)]

    def score(self, action: Array, answer: Array, scale: float) -> Array:
        """popgym's reward for an answer: ``+scale`` if right, ``-scale`` if wrong."""
        right = jnp.reshape(action, ()) == answer
        return jnp.where(right, scale, -scale).astype(jnp.float32)


class OneDeckTask(CardTask[CardState]):
    """A task on one shuffled pack: subclasses give the first observation and the step."""

    def reset_env(self, key: PRNGKey, params: EnvParams) -> tuple[CardState, Array]:
        """Shuffle the deck and deal its first card."""
        return self._start(self.shuffled(key))

    def state_from_vector(
        self, vector: Array, params: EnvParams | None = None
    ) -> tuple[CardState, Array]:
        """Start from a given deck: ``vector`` holds the card ids in dealing order."""
        return self._start(jnp.asarray(vector).astype(jnp.int32).reshape(self.num_cards))

    def _start(self, cards: Array) -> tuple[CardState, Array]:
        state = CardState(time=jnp.int32(0), cards=cards)
        return state, self.first_observation(cards)

    def first_observation(self, cards: Array) -> Array:
        """What the agent sees after the reset: by default the first card's suit."""
        return one_hot(suit_of(cards[0]), SUITS)


class RepeatPrevious(OneDeckTask):
    """``rl_jax/RepeatPreviousEasy-v0``, popgym's ``RepeatPreviousEasy``: name the suit of the
    ``k``-th most recent card (``k = 4``; the card just shown is the first).

    Each step (t = 1..51) scores the suit of card ``t - k``, ``+-1/48``, from step ``k`` on (no
    reward before), then deals card ``t``. Terminates at step 51, when one card is left.
    """

    k = 4

    def step_env(self, key: PRNGKey, state: CardState, action: Array, params: EnvParams):
        """Score the answer for card ``t - k`` (from step ``k`` on), deal card ``t``."""
        t = state.time + 1
        scale = 1.0 / (self.num_cards - self.k)
        answer = suit_of(self.dealt(state.cards, t - self.k))
        reward = jnp.where(t >= self.k, self.score(action, answer, scale), 0.0)
        obs = one_hot(suit_of(self.dealt(state.cards, t)), SUITS)
        terminated = t == self.num_cards - 1
        return CardState(time=t, cards=state.cards), obs, reward, terminated, {}


class RepeatFirst(OneDeckTask):
    """``rl_jax/RepeatFirstEasy-v0``, popgym's ``RepeatFirstEasy``: name the suit of the first
    card, shown only at the reset.

    Each step (t = 1..51) scores the answer, ``+-1/51``, and deals card ``t``. Terminates at step
    51, when one card is left.
    """

    def step_env(self, key: PRNGKey, state: CardState, action: Array, params: EnvParams):
        """Score the answer for the first card, deal card ``t``."""
        t = state.time + 1
        scale = 1.0 / (self.num_cards - 1)
        reward = self.score(action, suit_of(state.cards[0]), scale)
        obs = one_hot(suit_of(self.dealt(state.cards, t)), SUITS)
        terminated = t == self.num_cards - 1
        return CardState(time=t, cards=state.cards), obs, reward, terminated, {}


@struct.dataclass
class CountRecallState(CardState):
    """CountRecall's state: the dealt deck and a second, independently shuffled deck of
    queries."""

    queries: Array  # [num_cards] int32, card ids in dealing order


class CountRecall(CardTask[CountRecallState]):
    """``rl_jax/CountRecallEasy-v0``, popgym's ``CountRecallEasy``: each step shows the colour of
    a dealt card and the colour of a query card; the next action must say how many dealt cards
    of the queried colour have been shown so far (0..26).

    Each step (t = 1..51) scores the answer to the last query, ``+-1/51`` (the count includes
    the card shown with the query), then deals dealt card ``t`` and query ``t``. Terminates at
    step 51, when the dealt deck is empty.
    """

    def reset_env(self, key: PRNGKey, params: EnvParams) -> tuple[CountRecallState, Array]:
        """Shuffle both decks and deal the first card and query."""
        key_cards, key_queries = jax.random.split(key)
        return self._start(self.shuffled(key_cards), self.shuffled(key_queries))

    def state_from_vector(
        self, vector: Array, params: EnvParams | None = None
    ) -> tuple[CountRecallState, Array]:
        """Start from given decks: ``vector`` is the dealt deck then the query deck, each in
        dealing order."""
        decks = jnp.asarray(vector).astype(jnp.int32).reshape(2, self.num_cards)
        return self._start(decks[0], decks[1])

    def _start(self, cards: Array, queries: Array) -> tuple[CountRecallState, Array]:
        state = CountRecallState(time=jnp.int32(0), cards=cards, queries=queries)
        return state, self._observe(state, jnp.int32(0))

    def _observe(self, state: CountRecallState, index: Array) -> Array:
        """The colours of dealt card ``index`` and of query ``index``, one-hot each."""
        card = color_of(self.dealt(state.cards, index))
        query = color_of(self.dealt(state.queries, index))
        return jnp.concatenate([one_hot(card, COLORS), one_hot(query, COLORS)])

    @property
    def max_count(self) -> int:
        """The most cards of one colour in the deck: 26."""
        return self.num_cards // COLORS

    def action_space(self, params: EnvParams | None = None) -> Discrete:
        """A count, 0..26: popgym's ``Discrete(27)``."""
        return Discrete(self.max_count + 1)

    def observation_space(self, params: EnvParams | None = None) -> Box:
        """One-hot colour of the card just dealt, then one-hot colour of the query."""
        return _unit_box(2 * COLORS)

    def step_env(self, key: PRNGKey, state: CountRecallState, action: Array, params: EnvParams):
        """Score the count for the last query, deal the next card and query."""
        t = state.time + 1
        scale = 1.0 / (self.num_cards - 1)
        query = color_of(state.queries[t - 1])
        shown = jnp.arange(self.num_cards) < t  # cards 0..t-1 have been dealt
        count = jnp.sum(shown & (color_of(state.cards) == query))
        reward = self.score(action, count, scale)
        terminated = t == self.num_cards - 1
        state = CountRecallState(time=t, cards=state.cards, queries=state.queries)
        return state, self._observe(state, t), reward, terminated, {}


class Autoencode(OneDeckTask):
    """``rl_jax/AutoencodeEasy-v0``, popgym's ``AutoencodeEasy``: watch the whole deck dealt, then
    name its suits in reverse order.

    The observation is a one-hot mode (0 play, 1 watch, popgym's ``Mode``) and a one-hot suit.
    Steps 1..51 deal cards 1..51 with no reward; the mode turns to play with the last card
    shown. Steps 52..103 score the answer for card ``103 - t`` (the last card first),
    ``+-1/52``, and show mode play with suit 0, as popgym does. Terminates at step 103.
    """

    max_episode_steps = 2 * DECK_SIZE
    PLAY, WATCH = 0, 1

    def _observe(self, mode: Array | int, suit: Array | int) -> Array:
        return jnp.concatenate([one_hot(jnp.asarray(mode), 2), one_hot(jnp.asarray(suit), SUITS)])

    def first_observation(self, cards: Array) -> Array:
        """Mode watch and the first card's suit."""
        return self._observe(self.WATCH, suit_of(cards[0]))

    def observation_space(self, params: EnvParams | None = None) -> Box:
        """One-hot mode (play, watch), then one-hot suit."""
        return _unit_box(2 + SUITS)

    def step_env(self, key: PRNGKey, state: CardState, action: Array, params: EnvParams):
        """While watching, deal the next card; while playing, score the answer for the last
        card not yet named."""
        t = state.time + 1
        last = self.num_cards - 1
        watching = t <= last
        mode = jnp.where(t == last, self.PLAY, self.WATCH)
        watch_obs = self._observe(mode, suit_of(self.dealt(state.cards, t)))
        answer = suit_of(self.dealt(state.cards, 2 * last + 1 - t))
        play_reward = self.score(action, answer, 1.0 / self.num_cards)
        obs = jnp.where(watching, watch_obs, self._observe(self.PLAY, 0))
        reward = jnp.where(watching, 0.0, play_reward)
        terminated = t == 2 * last + 1
        return CardState(time=t, cards=state.cards), obs, reward, terminated, {}


def popgym_cards(deck_idx: np.ndarray) -> np.ndarray:
    """The dealing order of a popgym ``Deck`` after its reset (``deck.idx``): popgym deals from
    the end of the array."""
    return np.asarray(deck_idx)[::-1].copy()
