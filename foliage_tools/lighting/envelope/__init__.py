"""Per-leaf distances to the crown envelope, s_max, and the tree's optical thickness τ.

boulanger2008 (thesis, ch. 5) models a tree as leaves of area A, number density
ρ and uniformly distributed orientation inside an envelope. Light crossing a
layer of thickness s is attenuated by exp(-τ s) with τ = (A/2) ρ (eq. (5.5)),
and every leaf stores, for the 8 sample directions ω_j of eq. (5.28), the
distance s_max(P, ω_j) from its centre P to the envelope. This package computes
those distances and τ from the leaves themselves, by two algorithms, one
module per part:

* ``directions`` -- the sample directions ω_j (eq. (5.28)), the frame they are
  written in, and the bin (octant) of a vector;
* ``params`` -- :class:`EnvelopeParams` and :class:`EnvelopeResult`;
* ``solver`` -- :func:`solve`, the entry point: checks the leaves, takes a
  path, and gives s_max = D / τ and the attenuation;
* ``reference`` -- the paper's method (sec. 5.6), the **reference path**: the
  bins' optical depths D from all pairs of leaves (eq. (1) there), O(N²);
* ``tau`` -- estimating τ from the bins (``farthest``, ``moments``);
* ``fast`` -- the **fast path**: sum (1) split into an exact near field and a
  far field on a grid, O(N), and its accuracy;
* ``grid`` -- the fast path's grid and the cell of a point;
* ``near_field`` -- the near field's exact sums by cell lists;
* ``projection`` -- the far field's linear fit of a leaf's projected area over
  an octant;
* ``far_field`` -- the far field: cloud-in-cell deposits, FFT correlations
  with the octants' kernels, interpolation back to the leaves;
* ``boulanger`` -- the thesis' lighting of each leaf from its distances: direct
  sky and sun, one-bounce sun light and the higher orders;
* ``scatterer_sun`` -- the sun at a leaf's scatterers per octant, from the
  neighbours' exact lit fractions (eq. (5.20)).

Measurements behind some defaults (machine timings, settings tried) are in
``docs/envelope_notes.md``.

Pure numpy + numba + scipy; no USD, no files, no printing.
"""

from __future__ import annotations

from foliage_tools.lighting.envelope.directions import BIN_SOLID_ANGLE, N_DIRECTIONS, sample_directions, sample_frame
from foliage_tools.lighting.envelope.params import AUTO_FAST_THRESHOLD, EnvelopeParams, EnvelopeResult
from foliage_tools.lighting.envelope.params import PATHS as PATHS
from foliage_tools.lighting.envelope.params import TAU_ESTIMATORS as TAU_ESTIMATORS
from foliage_tools.lighting.envelope.solver import solve

# private parts that tests/unit/test_envelope*.py and benchmarks/bench_smax.py reach as ``envelope._name``
# (re-exported so that they keep working; the code itself imports them from their modules)
from foliage_tools.lighting.envelope.far_field import _far_field as _far_field
from foliage_tools.lighting.envelope.far_field import _grid_pad as _grid_pad
from foliage_tools.lighting.envelope.far_field import _irfftn_cropped as _irfftn_cropped
from foliage_tools.lighting.envelope.far_field import _rfftn_padded as _rfftn_padded
from foliage_tools.lighting.envelope.near_field import _near_sums as _near_sums
from foliage_tools.lighting.envelope.projection import _octant_projection as _octant_projection
from foliage_tools.lighting.envelope.reference import _reference_depths as _reference_depths
from foliage_tools.lighting.envelope.reference import _reference_kernel as _reference_kernel
from foliage_tools.lighting.envelope.tau import _estimate_tau as _estimate_tau

__all__ = [
    "AUTO_FAST_THRESHOLD",
    "BIN_SOLID_ANGLE",
    "N_DIRECTIONS",
    "EnvelopeParams",
    "EnvelopeResult",
    "sample_directions",
    "sample_frame",
    "solve",
]
