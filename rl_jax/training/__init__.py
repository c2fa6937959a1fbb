"""What makes the compiled program: the algorithm protocol, networks, replay (uniform,
prioritized, frame-stacked), the off-policy loop, the seeds x hyperparameters program and its
sharding, value ranges and the process-wide JAX settings."""
