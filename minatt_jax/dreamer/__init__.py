"""DreamerV3 with minimum attention, written for minatt-jax (``--algo dreamer``).

Modules: ``distributions`` (symlog, two-hot, latent categoricals, return normalization),
``networks`` (world model, actor, critic), ``config`` (the official proprioceptive settings and
our deviations), ``agent`` (losses, imagination, one update).
"""
