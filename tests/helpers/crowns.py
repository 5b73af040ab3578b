"""Synthetic crowns: leaves scattered uniformly in a ball (boulanger2008 sec. 5.2.1), as envelope inputs or as cards
to draw, and the surface optics the preview's shader tests draw them with."""

from __future__ import annotations

import math

import numpy as np

from foliage_tools.preview.optics import LeafOptics, SurfaceOptics
from foliage_tools.preview.renderer import face_normals

#: distinct values per face and channel, so a swapped face or channel cannot pass
LEAF = LeafOptics(
    reflectance_front=(0.10, 0.20, 0.30),
    reflectance_back=(0.05, 0.06, 0.07),
    transmittance_front=(0.02, 0.03, 0.04),
    transmittance_back=(0.11, 0.12, 0.13),
    specular=0.0,
)
OPTICS = SurfaceOptics(leaf=LEAF, ground_reflectance=(0.2, 0.3, 0.4))


def uniform_ball(n: int, *, tau: float = 2.0, radius: float = 1.0, seed: int = 1):
    """n leaves uniform in a ball, uniform orientation, area A = 2 τ / ρ (eq. (5.5))."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    centres = d * radius * rng.uniform(size=(n, 1)) ** (1.0 / 3.0)
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    density = n / (4.0 / 3.0 * math.pi * radius**3)
    return centres, normals, np.full(n, 2.0 * tau / density)


def crown(n=300, seed=5, radius=1.0, side=0.15):
    """(6n, 3) float32 corners of n random cards in a ball, their centres, unit normals and areas."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = d * radius * rng.uniform(size=(n, 1)) ** (1 / 3) + [0.0, 0.0, 2.0]
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    u, v = q[:, :, 0] * side / 2, q[:, :, 1] * side / 2
    a, b, cc, dd = c - u - v, c + u - v, c + u + v, c - u + v
    corners = np.stack([a, b, cc, a, cc, dd], axis=1).reshape(-1, 3).astype(np.float32)
    normals = face_normals(corners)[::6].astype(np.float64)
    return corners, c, normals, np.full(n, side * side)
