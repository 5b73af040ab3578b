"""Boundary conditions of the lattice-Boltzmann solver: one right-hand side per channel each.

The sun as boundary inflow or as a first-collision source, the Kronecker and ambient bases of steele2010
sec. 3.1; the package docstring (``lighting.lb``, "Update and boundary", "First-collision source") says how
each enters the lattice.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from foliage_tools.lighting.lb.lattice import UNIT_DIRECTIONS, barycentric_weights
from foliage_tools.lighting.lb.directions import NQ


@dataclass(frozen=True)
class Boundary:
    """One right-hand side: the density entering the grid along each moving direction, or a beam's first collisions."""

    name: str
    """``sun``, ``ambient`` or ``baseNN`` (NN = lattice index 01..18)."""
    inflow: tuple[float, ...]
    """18 values: b_i for lattice directions i = 1..18, the density of every inflow slot of direction i."""
    beam: tuple[float, float, float] | None = None
    """A collimated beam of irradiance 1 travelling along this unit vector, entering the grid from outside
    (``sun_source``): the right-hand side is its first-collision source and the lattice carries only
    scattered light (package docstring, "First-collision source"). ``inflow`` is then all zero."""

    def __post_init__(self) -> None:
        b = tuple(float(v) for v in self.inflow)
        object.__setattr__(self, "inflow", b)
        if len(b) != NQ or not all(math.isfinite(v) and v >= 0 for v in b):
            raise ValueError(f"a boundary needs 18 finite inflow densities >= 0, got {b}")
        if self.beam is not None:
            d = np.asarray(self.beam, dtype=np.float64).reshape(-1)
            n = float(np.linalg.norm(d)) if d.size == 3 else float("nan")
            if not (math.isfinite(n) and n > 0):
                raise ValueError(f"a beam direction must be a finite nonzero 3-vector, got {self.beam}")
            if any(b):
                raise ValueError("a beam right-hand side has no boundary inflow (its light enters as the first-collision source)")
            object.__setattr__(self, "beam", tuple(float(v) for v in d / n))


#: Ways ``sun_boundary`` splits the sun over the lattice directions.
SUN_SPLITS = ("geist2008", "flux")


def sun_boundary(sun_dir, split: str = "geist2008") -> Boundary:
    """The sun as boundary inflow along lattice directions; ``sun_dir`` points from the tree toward the sun.

    The light travels along d = -sun_dir.

    * ``geist2008`` (sec. 3): b_i proportional to max(0, n_i . d), summing to 1, so an empty
      grid holds u = 1 (the scalar irradiance of a unit sun). Its net flux ``sum_i b_i n_i`` is
      shorter than d and tilted: at elevation 60 degrees it brings 0.574 instead of 0.866 through
      a horizontal plane, and part of the light along horizontal lattice directions.
    * ``flux``: the three directions of the hull face hit by d (``lattice.barycentric_weights``)
      with b = M^-1 d, M their unit vectors as columns, so ``sum_i b_i n_i = d`` exactly: the
      right flux through every plane whose normal sees all three on the same side as d. The
      price is the scalar irradiance sum_i b_i = 1 / |hit point| in [1, 1.22] (> 1 off the
      lattice directions), since no non-negative mix of unit vectors other than d itself has
      both unit length and unit sum.

    The first-collision source ``sun_source`` needs neither compromise.
    """
    s = np.asarray(sun_dir, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(s))
    if not (math.isfinite(n) and n > 0):
        raise ValueError(f"sun_dir must be a finite nonzero 3-vector, got {tuple(s)}")
    if split not in SUN_SPLITS:
        raise ValueError(f"split must be one of {', '.join(SUN_SPLITS)}, got {split!r}")
    d = -s / n
    if split == "flux":
        idx, _ = barycentric_weights(d)
        cols = np.array(idx) - 1
        b = np.zeros(NQ)
        b[cols] = np.clip(np.linalg.solve(UNIT_DIRECTIONS[1:][cols].T, d), 0.0, None)
        return Boundary("sun", tuple(b))
    dots = np.clip(UNIT_DIRECTIONS[1:] @ d, 0.0, None)  # geist2008 sec. 3
    return Boundary("sun", tuple(dots / dots.sum()))


def sun_source(sun_dir, name: str = "sun") -> Boundary:
    """The sun (irradiance 1, ``sun_dir`` toward the sun) as a first-collision source (``Boundary.beam``)."""
    s = np.asarray(sun_dir, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(s))
    if not (math.isfinite(n) and n > 0):
        raise ValueError(f"sun_dir must be a finite nonzero 3-vector, got {tuple(s)}")
    return Boundary(name, (0.0,) * NQ, beam=tuple(-s / n))


def base_boundary(k: int) -> Boundary:
    """steele2010 sec. 3.1: B_k has inflow delta_ik (k = 1..18); B_0 (ambient) has inflow 1 everywhere."""
    if not (isinstance(k, (int, np.integer)) and 0 <= k <= 18):
        raise ValueError(f"base index must be an integer in 0..18, got {k!r}")
    if k == 0:
        return ambient_boundary()
    b = np.zeros(NQ)
    b[k - 1] = 1.0
    return Boundary(f"base{k:02d}", tuple(b))


def ambient_boundary() -> Boundary:
    """steele2010 sec. 3.1, B_0: f_i = 1 on the boundary for all i."""
    return Boundary("ambient", tuple(np.ones(NQ)))


def relighting_boundaries() -> tuple[Boundary, ...]:
    """The 19 base conditions B_0 (ambient), B_1 .. B_18 of steele2010 sec. 3.1, in lattice order."""
    return tuple(base_boundary(k) for k in range(19))
