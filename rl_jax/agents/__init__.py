"""The learners, one module each: ``td3`` (TD3 and DDPG), ``td7``, ``crossq``, ``sac``, ``ppo``,
``dqn`` and ``reinforce``, each with its maths, its learner on the training machinery and its
recipes per env. What several of them share: ``actor_critic`` (the deterministic actor-critics'
settings, networks, exploration and targets), ``common`` (the optimizer step, rate schedules,
gradient clipping, target steps) and pure maths (``q_learning``, ``policy_gradient``)."""
