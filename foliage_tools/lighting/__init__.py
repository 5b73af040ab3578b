"""Lighting solvers: pure numerics, no USD or files."""
