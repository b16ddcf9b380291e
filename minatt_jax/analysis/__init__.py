"""Analysis of trained policies: ``control_analysis`` (K(t) x + v(t), feedback along rollouts,
failures), ``report`` (``minatt-jax analyze``: tables, heatmaps, failure grid, HTML) and
``plots`` (figures of curves and meta-tests)."""
