"""Partially observed envs, for learners with memory: velocity-masked classic and MuJoCo envs
under the ids people compare recurrent learners on (``masked``), and POPGym's memory tasks in JAX
(``cards``: RepeatPrevious, RepeatFirst, CountRecall, Autoencode; ``stateless_cartpole``)."""
