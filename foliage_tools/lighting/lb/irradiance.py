"""Outputs of the lattice-Boltzmann lighting: irradiance on a leaf and the relighting blend of the bases.

The package docstring (``lighting.lb``, "Units: what the field means") derives E_leaf = u / 2.
"""

from __future__ import annotations

import numpy as np

from foliage_tools.lighting.lb.lattice import barycentric_weights


def leaf_irradiance(energy_density):
    """Irradiance (both faces summed) on a randomly oriented two-sided leaf: E = u / 2.

    Each lattice beam f_i is a collimated beam of perpendicular irradiance
    f_i; a leaf with normal N receives f_i |N . n_i| from it over its two
    faces, and the mean of |N . n| over uniformly random N is 1/2. So
    E = 1/2 sum_i f_i = u / 2. An empty grid under a unit sun gives E = 1/2.
    """
    return np.asarray(energy_density) * 0.5


def scattered_leaf_irradiance(energy_density, unscattered_energy_density):
    """E_scattered = (u - u_unscattered) / 2, u_unscattered from ``unscattered_energy(problem)``.

    The difference is the light scattered at least once (including light
    scattered forward into its own direction); the factor 1/2 is that of
    ``leaf_irradiance``.
    """
    return (np.asarray(energy_density) - np.asarray(unscattered_energy_density)) * 0.5


def relight(bases, sun_dir, *, ambient: float = 0.0) -> np.ndarray:
    """Blend base solutions for a sun direction (steele2010 sec. 3.1).

    Parameters
    ----------
    bases : (..., 19, C) array
        Base solutions B_0 .. B_18 along axis -2 (``solve`` with
        ``relighting_boundaries()`` gives ``energy_density`` of shape
        (nx, ny, nz, 19, C)).
    sun_dir : (3,) toward the sun, in the bases' (prototype) frame.
    ambient : float
        Scale of the ambient base B_0 added to the sun (user-controlled in steele2010).

    Returns
    -------
    (..., C): ``sum_k w_k B_{i_k} + ambient * B_0``, where (i_k, w_k) are the
    hull face and barycentric weights hit by the light's travel direction
    ``-sun_dir`` (weights >= 0, summing to 1).
    """
    b = np.asarray(bases)
    if b.ndim < 2 or b.shape[-2] != 19:
        raise ValueError(f"bases must have the 19 base solutions on axis -2, got shape {b.shape}")
    idx, w = barycentric_weights(-np.asarray(sun_dir, dtype=np.float64))
    out = w[0] * b[..., idx[0], :] + w[1] * b[..., idx[1], :] + w[2] * b[..., idx[2], :]
    if ambient:
        out = out + ambient * b[..., 0, :]
    return out
