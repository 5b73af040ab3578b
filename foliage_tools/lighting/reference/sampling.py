"""Directions for the Monte Carlo reference (vectorised numpy): orthonormal bases about unit vectors,
cosine-distributed and uniform directions on a hemisphere."""

from __future__ import annotations

import math

import numpy as np


def _onb(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing unit normals n (K, 3) to orthonormal bases.

    Duff et al. 2017, "Building an Orthonormal Basis, Revisited", JCGT 6(1), listing 3.
    """
    sign = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t1 = np.stack([1.0 + sign * n[:, 0] * n[:, 0] * a, sign * b, -sign * n[:, 0]], axis=1)
    t2 = np.stack([b, sign + n[:, 1] * n[:, 1] * a, -n[:, 1]], axis=1)
    return t1, t2


def _cosine_directions(axis: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Cosine-distributed unit directions about unit ``axis`` (K, 3) (Malley's method:
    uniform on the unit disc, projected up to the hemisphere)."""
    r = np.sqrt(u1)
    phi = 2.0 * math.pi * u2
    z = np.sqrt(np.maximum(0.0, 1.0 - u1))
    t1, t2 = _onb(axis)
    return (r * np.cos(phi))[:, None] * t1 + (r * np.sin(phi))[:, None] * t2 + z[:, None] * axis


def _uniform_hemisphere(axis: np.ndarray, u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """Directions uniform (pdf 1/2π) on the hemisphere about one unit ``axis`` (3,)."""
    z = u1
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = 2.0 * math.pi * u2
    t1, t2 = _onb(axis[None, :])
    return (r * np.cos(phi))[:, None] * t1 + (r * np.sin(phi))[:, None] * t2 + z[:, None] * axis[None, :]
