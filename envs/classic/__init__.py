"""Classic-control envs in pure JAX: the rocket (and its control-theory controllers), cart-pole
(from state and from pixels), the pendulum, and their drawing."""
