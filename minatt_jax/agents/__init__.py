"""Agents: one module per algorithm behind one interface (``base.Agent``), and their registry.

``registry.get(name)`` returns an algorithm's ``AgentSpec`` (importing a built-in agent's module
on first use; a plugin's through its entry point); ``registry.register(spec)`` adds a user's.
Modules: ``sac``, ``ppo``, ``mbpo``, ``mbmpo``, ``dreamer``, ``mamba``.
"""
