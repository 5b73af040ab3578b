"""Tolerances and limits of the plane-parallel solver.

The resonance tolerance and step, the threshold below which the conservative
eigenvalue is refined (both explained in the package docstring,
:mod:`foliage_tools.lighting.plane_parallel`), the largest number of streams and the
message for a phase function too peaked for the streams.
"""

from __future__ import annotations

#: Relative distance |k mu0 - 1| under which the particular solution is treated
#: as resonant (see package docstring).
RESONANCE_TOLERANCE = 1e-5
#: Relative perturbation of mu0 used at a resonance.
RESONANCE_STEP = 4e-5
#: Below this 1 - omega, the smallest m = 0 eigenvalue is refined by the
#: deflated iteration (relative accuracy near conservative scattering).
CONSERVATIVE_REFINE_BELOW = 1e-4
_PEAKED_MESSAGE = (
    "the phase function is too strongly peaked for this number of streams (its Legendre series "
    "truncated after 2 * n_streams terms makes Fourier order {m} indefinite); increase n_streams "
    "(about 0.6 / (1 - |g|) streams are needed for Henyey-Greenstein)"
)
#: Largest number of streams per hemisphere accepted.
MAX_STREAMS = 256
