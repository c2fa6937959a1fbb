"""The algorithms: TD3 and DDPG (``td3``), DQN (``dqn``), REINFORCE (``reinforce``), each its
maths, its learner on the training machinery and its recipes per env."""
