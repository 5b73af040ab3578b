"""The sample directions (a spherical Fibonacci set about ``up``, package docstring of
:mod:`foliage_tools.lighting.gfactor`), the sky's weights on them, and the unit-vector and frame helpers the other
modules share.
"""

from __future__ import annotations

import math

import numpy as np

from foliage_tools.lighting.gfactor.params import DEFAULT_DIRECTIONS


def _unit(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or not np.any(a != 0.0):
        raise ValueError(f"{name} must be a finite non-zero 3-vector, got {v!r}")
    return a / np.linalg.norm(a)


def _frame(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``up`` to a right-handed orthonormal frame."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(helper, up)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    return e1, e2


def sample_directions(n: int = DEFAULT_DIRECTIONS, *, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Spherical Fibonacci directions about ``up`` (package docstring).

    Parameters
    ----------
    n : int
        Number of directions, even, >= 2 (the sky uses the n/2 upper ones).
    up : array_like (3,)
        The stage's up axis.

    Returns
    -------
    numpy.ndarray, shape (n, 3)
        Unit vectors; ``directions @ up = 1 - (2i + 1)/n``.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2 or n % 2:
        raise ValueError(f"the number of sample directions must be an even integer >= 2, got {n!r}")
    upv = _unit(up, "up")
    e1, e2 = _frame(upv)
    i = np.arange(n, dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = i * math.pi * (3.0 - math.sqrt(5.0))  # golden angle
    return (r * np.cos(phi))[:, None] * e1 + (r * np.sin(phi))[:, None] * e2 + z[:, None] * upv


def sky_weights(directions, *, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Beam irradiance W_j of each sample direction standing for a uniform sky.

    Equal weights (the Fibonacci directions have equal solid angles) on the
    directions above the horizon, zero below, scaled so that Σ W_j μ_j = 1: the
    horizontal irradiance of a uniform sky of radiance 1/π.
    """
    d = np.asarray(directions, dtype=np.float64)
    mu = d @ _unit(up, "up")
    upper = mu > 0.0
    if not np.any(upper):
        raise ValueError("no sample direction is above the horizon; cannot represent the sky")
    w = np.where(upper, 1.0, 0.0)
    return w / float(np.sum(w * np.where(upper, mu, 0.0)))
