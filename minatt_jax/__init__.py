"""minatt-jax: meta-reinforcement learning with minimum attention, end to end in JAX/MJX."""

__version__ = "0.1.0"
