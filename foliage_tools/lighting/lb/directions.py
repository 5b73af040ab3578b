"""The 18 moving directions as the lattice-Boltzmann solver stores them, and the power each carries.

Direction q of the state is lattice direction q + 1 (``lighting.lattice``); the opposite pairs are (2p, 2p + 1),
the first ``NAXIAL_PAIRS`` of them axial. The package docstring (``lighting.lb``) describes the state.
"""

from __future__ import annotations

import numpy as np

from foliage_tools.lighting.lb.collision import LATTICES
from foliage_tools.lighting.lb.lattice import DIRECTIONS, STEP_LENGTHS

NQ = 18  # moving directions 1..18 stored at index q = i - 1
_CX = np.ascontiguousarray(DIRECTIONS[1:, 0])
_CY = np.ascontiguousarray(DIRECTIONS[1:, 1])
_CZ = np.ascontiguousarray(DIRECTIONS[1:, 2])
NH = NQ // 2  # opposite pairs: direction 2p + 1 is the opposite of 2p (checked in _parity_blocks)
NAXIAL_PAIRS = 3  # pairs 0..2 are the axial directions 1..6, pairs 3..8 the non-axial 7..18


def power_weights(lattice: str) -> np.ndarray:
    """(18,) wq_i with power ``sum_i wq_i f_i``: 1 / |c_i| on the ``ordinates`` lattice (a line of
    direction c_i stands for the cross-section dx^2 / |c_i|, ``collision``), 1 on ``geist2008``
    (which conserves the density sum)."""
    if lattice not in LATTICES:
        raise ValueError(f"lattice must be one of {', '.join(LATTICES)}, got {lattice!r}")
    return 1.0 / STEP_LENGTHS[1:] if lattice == "ordinates" else np.ones(NQ)
