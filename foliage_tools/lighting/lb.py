"""Lattice-Boltzmann lighting solver (geist2008 sec. 2.2-3, steele2010 sec. 3.1).

Update and boundary
-------------------
geist2008 eq. (2): ``f_m(r + c_m, t+1) = f_m(r, t) + rho(r) Omega_m . f(r, t)``,
with Omega of ``collision.omega`` (eqs. (5)-(9)) scaled by the node density,
then the rest component f_0 - the energy absorbed at the node in this step -
is zeroed at every node (geist2008 sec. 3), so only the 18 moving directions
carry state. ``f_m(r, t)`` is the density *arriving* at r along c_m; that is
what the solver stores, and what the residual and the output are made of.
On the default ``ordinates`` lattice (``LBProblem.lattice``; derivation in
``collision``) the common factor rho becomes one per step length, ``f_i +
sum_j A_ij rho_j f_j`` with rho_j = 1 - (1 - rho)^|c_j|, so a diagonal step
attenuates over its sqrt(2) dx, and the in-scattering carries the power
``sum_i f_i / |c_i|`` (what ``inflow``, ``outflow`` and ``absorbed`` count,
``power_weights``); ``lattice="geist2008"`` is the paper's update.

The grid is the cropped density grid; its boundary is a ghost layer just
outside it. A slot ``f_i(r)`` whose upstream node ``r - c_i`` lies outside the
grid is an *inflow* slot and holds the boundary density ``b_i`` for ever
(the paper's fixed boundary densities); light that streams out of the grid
is gone (outflow). Boundary conditions (each is one right-hand side per
channel), with ``n_i = c_i / |c_i|``:

* ``sun_boundary(sun_dir)``: ``b_i ∝ max(0, n_i . d)`` with d = -sun_dir the
  direction the light travels (geist2008 sec. 3: densities proportional to
  the positive dot products), normalised so ``sum_i b_i = 1``: in an empty
  grid the field is then a sun of irradiance 1 (see "Units" below).
* ``base_boundary(k)``, k = 1..18: ``b_i = delta_ik`` (steele2010 sec. 3.1,
  Kronecker base B_k, a unit beam travelling along c_k).
* ``base_boundary(0)`` / ``ambient_boundary()``: ``b_i = 1`` for all i
  (steele2010 sec. 3.1, ambient base B_0).
* ``sun_source(sun_dir)`` (``Boundary.beam``): no inflow at all; see below.

First-collision source
----------------------
A sun that is not a lattice direction cannot enter as boundary inflow
without error: ``sun_boundary`` spreads it over up to 8 lattice directions
(geist2008) and the lattice then carries those slanted beams, each with its
own attenuation (issue #15: at 30 degrees the lattice's own unscattered light
was +271 % in the deepest bin of a layer), or carries the right flux with too
much scalar irradiance (``split="flux"``). Transport theory's first-collision
source avoids both: the unscattered sun is attenuated exactly along its own
direction (``beam_fields``: a march through the node densities), scattered
once at every node into the lattice directions by the phase function, and
that source, added after the collision in every sweep (the affine sweep T f
+ S s; BiCGSTAB takes it as its right-hand side), is all the lattice
carries: its field is the scattered light, nothing is subtracted.
``energy_density`` adds the exact unscattered beam at the node centres
(``unscattered_energy``), so u is the total for every kind of right-hand
side. For a beam along a lattice direction the two formulations agree
exactly (the Kronecker bases of ``--bases all`` are such beams).

Stability policy: reject
------------------------
With ``rho * sigma_t <= 1`` at every node the update matrix ``I + rho Omega``
(moving block) is non-negative with column sums ``1 - rho sigma_a <= 1``, so
the iteration cannot amplify anything. Above 1 its diagonal goes negative and
the explicit update oscillates and can grow. ``LBProblem`` refuses such input
with ``LatticeStabilityError`` (a ``ValueError`` and a ``UsageError``) that
names the offending maximum. It does not clamp: clamping silently changes the
medium. ``collision.density_from_lad`` maps leaf-area density to rho < 1, so
the error only arises from densities made some other way or sigma_t > 1; the
remedy is smaller voxels (rho grows with the voxel size) or that mapping.

Units: what the field means
---------------------------
A lattice beam with ``f_i = 1`` is a collimated beam of irradiance 1 on a
plane perpendicular to it; on the ordinates lattice f_i is the irradiance
carried by ordinate i (its lines, |c_i| times denser across the beam for the
diagonals, carry the power f_i dx^2 / |c_i| each; ``collision``). The output
per node is the total photon density ``u = sum_i f_i``, the scalar irradiance
(4 pi x the mean radiance, the "actinic flux" of ``plane_parallel``): the
"radiant energy density" the renderer samples, geist2008 sec. 3: "a total
photon density per component at each grid node". A unit beam gives u = 1.

Irradiance on a leaf. A two-sided leaf with unit normal N at the node receives
from beam i the irradiance ``f_i |N . n_i|`` summed over its two faces (one
face is lit, the other gets nothing from that beam). For a randomly oriented
leaf (N uniform on the sphere), ``E|N . n| = int_0^1 mu dmu = 1/2`` for every
n, so

    E_leaf(x) = 1/2 sum_i f_i(x) = u(x) / 2                  (``leaf_irradiance``)

and ``E_scattered = (u - u_unscattered) / 2`` (``scattered_leaf_irradiance``),
where u_unscattered is the solution of ``LBProblem.unscattered()`` (computed
exactly in one pass by ``unscattered_energy``): the same
lattice with sigma_s = 0 and sigma_a = sigma_t, whose per-step factor
``1 - rho_i sigma_t`` is exactly the never-scattered part of the full update;
for a beam it is the exact beam at the node centre, and u - u_unscattered is
the lattice field itself. Check: an empty grid under the sun gives u = 1 and
E_leaf = 1/2, the exact irradiance of a randomly oriented two-sided leaf in a
sun of irradiance 1; in a uniform slab a beam's u_unscattered is the exact
solver's direct actinic flux exp(-tau/mu0) to round-off, and the lattice's u
its diffuse one up to the lattice's angular error (tests/unit/test_lb_slab.py,
which also says why that error stays +20 .. +42 % in the top fifth of a
plane-parallel layer at every resolution).

Layout and kernel
-----------------
The state is ``(nx, NB, 18, C, G * nz, K)`` float32 (C channels, K boundary
conditions; the right-hand sides are the C*K pairs; direction q is lattice
direction q + 1): the rows of G consecutive y form one block, whose values of
one direction and channel are one contiguous run of G nz K values (node
(x, y, z) at ``[x, y // G, :, :, (y % G) nz + z]``; the last block is padded
with zero rows). Fused numba kernels (``parallel=True``, ``prange`` over x) do
collision and push-streaming for all right-hand sides at once: the SIMD
dimension is the contiguous run of one direction and channel, over which the
channel's collision coefficients are broadcast scalars, and streaming is a
shifted copy of that run into the target. So the bases are innermost, as
asked, but with z (and y % G) between them and the channel. Why: with the
right-hand sides alone innermost, ``(nx, ny, nz, 18, R)``, the vectors are R
long (3 for the sun in RGB: no SIMD at all) and streaming moves 18 short runs
per node, which measured 1.6-2x slower (README "Speed"; ``benchmarks/bench_lb_issue.py``
times the kernels). Memory: 72 C K bytes per node and field (64^3
with 19 bases x RGB: 1.08 GB); plain iteration holds 2 fields, BiCGSTAB 6.

Storage (``LBParams.storage``, ``lighting.storage``): the state is float32
(``fp32``) or binary16 bits in uint16 (``fp16``: 36 C K bytes per node and
field). The kernels read every stored density through ``storage.load`` and
write through ``storage.convert`` (identities for float32, so the fp32 path
is the same code as before), and do all arithmetic in float32, the dtype of
``rho``, which also types their scratch arrays: FluidX3D's FP16 storage with
FP32 arithmetic. Each stored value is rounded once per sweep, except in the
hand loop of short occupied runs with a beam source, which rounds after the
collision and again after the source. Pass-through copies move the 16-bit
values unchanged. The residual is that of the stored (rounded) values, so an
fp16 iteration ends at a fixed point of the rounded map, whose distance from
the exact steady state is bounded by 2^-11 (I - T)^-1 |f| componentwise
(tests/unit/test_lb_storage.py). BiCGSTAB is not offered with fp16.

Occupied nodes collide by the parity split of ``_parity_blocks``: two (9 x 9)
@ (9 x n) products per channel and material on rho (f_2p +- f_2p+1), written
out three output rows per pass (``_pair_product``: their coefficients stay in
registers, which outruns BLAS gemm through ``np.dot`` on such thin products),
and the post-collision values go straight into their target slots while
streaming (never stored after collision). Empty parts are copied.

* Long rows (nz K >= ``_ROW_KERNEL_MIN`` values: many right-hand sides) are
  blocks of one row (G = 1) and ``_sweep_rows`` sweeps them row by row; an
  occupied run shorter than ``_LONG_RUN_MIN`` there keeps a hand loop, where
  the products' per-call costs eat their gain.
* Short rows (few right-hand sides, e.g. the sun: nz values per direction
  and channel) are blocks of G = ``_BLOCK_VALUES`` // (nz K) rows, and
  ``_sweep_blocks`` collides and streams whole blocks: a y- and z-shift is one
  offset of the flat run, the row that crosses into a neighbouring block goes
  there, and the few slots a z-shift wraps into (inflow slots on the z faces
  of the next row) are saved and put back. Sweeping such rows one by one
  runs loops over only 64-128 values, which measured slower at 1-3 rhs.

``_reference_step`` is the plain numpy version of the update on the paper's 19
directions that both kernels are tested against.

Steady state
------------
Every solver starts from the exact never-scattered field (``LBParams.initial``,
``unscattered_energy``; for a beam, from its once-scattered light: the source
carried along the lattice lines in one ordered pass, ``_once_scattered``), so
the direct beam is in place from sweep 0 and the iteration converges only the
scattered light: on the example tree at 64^3 and
tolerance 1e-5 that took 140 instead of 168 sweeps for the sun and 124
instead of 168 for the 18 bases. The steady state solves ``(I - T) f = beta`` where T is one sweep with zero
boundary inflow and beta holds the boundary densities in the inflow slots.
``solver="iterate"`` repeats sweeps until the relative residual
``||f_{t+1} - f_t|| / ||f_t||`` of every right-hand side is below the
tolerance (measured every ``check_every`` sweeps). ``solver="bicgstab"``
runs BiCGSTAB on ``I - T`` for all right-hand sides in lock-step, each with
its own scalars but one kernel call per matrix-vector product for the whole
batch (scipy's ``bicgstab`` takes one vector at a time, which would run the
kernel without its batch); the products ``(I - T) v`` and the dot products
that follow them are fused into the sweep. ``"auto"`` iterates, estimates the
per-sweep contraction rate q from the residual history once the light has
had time to cross the grid, and switches to BiCGSTAB (warm-started from the
current field) when the predicted remaining sweeps ``log(tol/res)/log(q)``
exceed ``LBParams.switch_sweeps``; low absorption (q near 1) is where that
happens. BiCGSTAB holds 6 fields; if they do not fit in
``LBParams.memory_limit``, auto continues instead with
``solver="extrapolate"``: plain sweeps plus, whenever a right-hand side's
per-sweep residual ratio q has settled, a jump ``f + (f - f_prev) q/(1 - q)``
that sums the geometric tail of its slowest mode (Lyusternik extrapolation;
no extra memory, a heuristic: it relies on one real dominant mode, and
merely does not help when there is none). Every solver ends with a plain sweep, and the residual it reports
is that sweep's ``||f_{t+1} - f_t|| / ||f_t||``, the same quantity for all
solvers. This residual is not the error, which is about residual / (1 - q):
on a 32^3 dense sphere at tolerance 1e-6 the largest node error was 2e-5
(sigma_a = 0.1) to 2e-4 (0.001) for plain iteration and 3-4x smaller for
BiCGSTAB. Tighten the tolerance (float64 for < 1e-7) when the error matters.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Literal, overload

import numpy as np
from numba import njit, prange

from foliage_tools.errors import UsageError
from foliage_tools.lighting.collision import (
    LATTICES,
    Medium,
    brown,
    diagonal_density,
    source_weights,
    unit_moving_block,
)
from foliage_tools.lighting.depth import _march
from foliage_tools.lighting.lattice import DIRECTIONS, OPPOSITE, STEP_LENGTHS, UNIT_DIRECTIONS, barycentric_weights
from foliage_tools.lighting.storage import STORAGES, convert, from_storage, load, storage_dtype, to_storage

log = logging.getLogger(__name__)

__all__ = [
    "Boundary",
    "LBParams",
    "LBProblem",
    "LBResult",
    "LBNumericalError",
    "LatticeStabilityError",
    "ambient_boundary",
    "base_boundary",
    "leaf_irradiance",
    "memory_bytes",
    "relight",
    "BeamFields",
    "SUN_SPLITS",
    "beam_fields",
    "power_weights",
    "relighting_boundaries",
    "scattered_leaf_irradiance",
    "solve",
    "sun_boundary",
    "sun_source",
    "unscattered_energy",
]

NQ = 18  # moving directions 1..18 stored at index q = i - 1
_CX = np.ascontiguousarray(DIRECTIONS[1:, 0])
_CY = np.ascontiguousarray(DIRECTIONS[1:, 1])
_CZ = np.ascontiguousarray(DIRECTIONS[1:, 2])
SOLVERS = ("auto", "iterate", "bicgstab", "extrapolate")
#: Rows of nz K values at least this long (many right-hand sides) are swept one row at a time (``_sweep_rows``);
#: shorter ones in blocks of ``_BLOCK_VALUES`` // (nz K) rows (``_sweep_blocks``), so that its loops run over
#: about that many values.
_ROW_KERNEL_MIN = 1024
#: (3 rhs on a uniformly occupied 64^3 grid, while the kernel was written: 7.3 ms per sweep with 4096, 8.7 with
#: 2048, 9.1 with 1024; one run each.)
_BLOCK_VALUES = 4096
#: ``_sweep_rows``: occupied runs at least this long collide by the parity-split products, shorter ones by the hand loop.
_LONG_RUN_MIN = 256
NH = NQ // 2  # opposite pairs: direction 2p + 1 is the opposite of 2p (checked in _parity_blocks)
NAXIAL_PAIRS = 3  # pairs 0..2 are the axial directions 1..6, pairs 3..8 the non-axial 7..18


def _parity_blocks(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Even and odd parts (..., 9, 9) of moving blocks A (..., 18, 18) over the opposite pairs (2p, 2p + 1).

    With s_p = f_2p + f_2p+1 and d_p = f_2p - f_2p+1, ``(A f)_2p = (AE s + AO d)_p`` and
    ``(A f)_2p+1 = (AE s - AO d)_p``, where AE = (A[2p, 2q] + A[2p, 2q+1]) / 2 and
    AO = (A[2p, 2q] - A[2p, 2q+1]) / 2. This needs A to commute with inversion, which holds for
    every Omega of geist2008 eqs. (5)-(9) (it depends only on the angle between directions); a
    block that does not is refused rather than solved wrongly.
    """
    opp = np.asarray(OPPOSITE[1:]) - 1
    if not np.array_equal(opp, np.arange(NQ) ^ 1):
        raise AssertionError("lattice order changed: direction 2p + 1 must be the opposite of 2p")
    if not np.allclose(A[..., opp, :][..., :, opp], A, rtol=0, atol=1e-12 * max(1.0, float(np.abs(A).max()))):
        raise ValueError("the collision block does not commute with inversion c -> -c; the kernel's parity split needs it")
    even, odd = A[..., 0::2, 0::2], A[..., 0::2, 1::2]
    return (even + odd) / 2, (even - odd) / 2


class LatticeStabilityError(UsageError, ValueError):
    """rho * sigma_t > 1 somewhere: the explicit lattice update would be unstable."""


class LBNumericalError(ArithmeticError):
    """The solver produced non-finite values (raised instead of returning them).

    Not a :class:`~foliage_tools.errors.FoliageError`: it is no fault of the input, so the command line treats it as
    any internal failure (exit 3, with a crash log holding the traceback)."""


#: Largest per-sweep ratio q an extrapolation jump f + (f - f_prev) q / (1 - q) uses (a jump of at most 199x the
#: last change: a larger one, from a ratio that only looked settled, once overflowed float32 at 64^3 with 18 bases).
_MAX_EXTRAPOLATION_Q = 0.995


# --------------------------------------------------------------------------- boundaries


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
    scattered light (module docstring, "First-collision source"). ``inflow`` is then all zero."""

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


# --------------------------------------------------------------------------- problem / params / result


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields explicitly
class LBProblem:
    """A lighting problem on one cropped grid: node densities, media and boundary conditions."""

    density: np.ndarray
    """(nx, ny, nz) node density rho in [0, 1] (per-step interaction probability;
    see ``collision.density_from_lad``). Stored as a read-only float64 copy."""
    medium: Medium
    """Coefficients of green (leaf) nodes, per channel."""
    boundaries: tuple[Boundary, ...]
    """Boundary conditions to solve for; each gives one right-hand side per channel."""
    brown_mask: np.ndarray | None = None
    """(nx, ny, nz) bool: wood-dominated ("brown") nodes (geist2008 sec. 3), or None."""
    brown_medium: Medium | None = None
    """Coefficients of brown nodes; default ``collision.brown(medium)`` (same sigma, g = -1)."""
    lattice: str = "ordinates"
    """``ordinates`` (true step lengths and ordinate weights) or ``geist2008`` (the paper's one density per
    node for every step); see ``collision``. Beams (first-collision sources) need ``ordinates``."""

    def __post_init__(self) -> None:
        if self.lattice not in LATTICES:
            raise ValueError(f"lattice must be one of {', '.join(LATTICES)}, got {self.lattice!r}")
        rho = np.array(self.density, dtype=np.float64)
        if rho.ndim != 3 or min(rho.shape) < 1:
            raise ValueError(f"density must be a 3D grid, got shape {rho.shape}")
        if not np.all(np.isfinite(rho)) or rho.min() < 0:
            raise ValueError("density must be finite and >= 0 everywhere")
        rho.flags.writeable = False
        object.__setattr__(self, "density", rho)
        bounds = tuple(self.boundaries)
        if not bounds or not all(isinstance(b, Boundary) for b in bounds):
            raise ValueError("boundaries must be a nonempty sequence of Boundary")
        object.__setattr__(self, "boundaries", bounds)
        if self.lattice != "ordinates" and any(b.beam is not None for b in bounds):
            raise ValueError("a beam (first-collision source) needs the ordinates lattice: the geist2008 steps have no "
                             "geometry to march a beam through")
        mask = None
        if self.brown_mask is not None:
            mask = np.array(self.brown_mask, dtype=bool)
            if mask.shape != rho.shape:
                raise ValueError(f"brown_mask has shape {mask.shape}, density has {rho.shape}")
            mask.flags.writeable = False
        object.__setattr__(self, "brown_mask", mask)
        bm = self.brown_medium if self.brown_medium is not None else brown(self.medium)
        if bm.channels != self.medium.channels:
            raise ValueError(f"brown medium has {bm.channels} channels, medium has {self.medium.channels}")
        object.__setattr__(self, "brown_medium", bm)
        self._check_stability()

    def _check_stability(self) -> None:
        for name, med, sel in (("green", self.medium, self._green()), ("brown", self.brown_medium, self.brown_mask)):
            if sel is None or not sel.any():
                continue
            assert med is not None  # brown_medium: set by __post_init__ before this runs
            rho = np.where(sel, self.density, 0.0)
            flat = int(np.argmax(rho))
            rmax = float(rho.flat[flat])
            c = int(np.argmax(med.sigma_t))
            worst = rmax * med.sigma_t[c]
            if self.lattice == "ordinates":
                # the non-axial steps meet leaves with rho_d = 1 - (1 - rho)^sqrt2 >= rho (needs rho <= 1)
                worst = max(worst, float(diagonal_density(min(rmax, 1.0))) * med.sigma_t[c])
                if rmax > 1.0:
                    worst = max(worst, rmax)
            if worst > 1.0 + 1e-9:
                node = tuple(int(v) for v in np.unravel_index(flat, rho.shape))
                raise LatticeStabilityError(
                    f"max rho * sigma_t = {worst:.4g} > 1 ({name} node {node}: rho = {rmax:.4g}, "
                    f"sigma_t = {med.sigma_t[c]:.4g} in channel {c}): the explicit lattice update "
                    "(geist2008 eq. 2) is unstable there. Use smaller voxels (a higher resolution: "
                    "rho grows with the voxel size), build rho with collision.density_from_lad "
                    "(which keeps rho < 1), or keep sigma_a + sigma_s <= 1."
                )

    def _green(self) -> np.ndarray:
        return np.ones(self.density.shape, bool) if self.brown_mask is None else ~self.brown_mask

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.density.shape  # type: ignore[return-value]

    @property
    def channels(self) -> int:
        return self.medium.channels

    def unscattered(self) -> LBProblem:
        """The same problem for never-scattered light (sigma_s = 0, sigma_a = sigma_t): gives u_unscattered."""
        assert self.brown_medium is not None  # __post_init__ defaults it to brown(medium)
        return LBProblem(self.density, self.medium.unscattered(), self.boundaries, self.brown_mask,
                         self.brown_medium.unscattered(), self.lattice)


@dataclass(frozen=True)
class LBParams:
    """How ``solve`` runs."""

    tolerance: float = 1e-6
    """Stop when ||f_{t+1} - f_t|| / ||f_t|| < tolerance for every right-hand side."""
    max_sweeps: int = 20000
    """Upper bound on lattice sweeps (operator applications); the result says whether it converged."""
    solver: str = "auto"
    """``iterate`` (plain sweeps), ``bicgstab`` (batched BiCGSTAB), ``extrapolate`` (plain sweeps with
    Lyusternik extrapolation, no extra memory) or ``auto`` (iterate; when slow, BiCGSTAB if its 6
    fields fit in ``memory_limit``, else extrapolation)."""
    switch_sweeps: int = 300
    """``auto``: switch to BiCGSTAB when plain iteration predicts more than this many further sweeps.

    Break-even model: from a warm start BiCGSTAB took about 4.5 sqrt(S) sweeps
    where plain iteration needed S more (64^3 sphere, sigma_a = 0.01 and
    0.001), and a BiCGSTAB sweep costs 2-4 plain ones (its 5 vector passes per
    2 sweeps are memory-bound; 4 with 3 right-hand sides, 2 with 57). Equal
    time at S = (4.5 * 4)^2 ~ 300 for few right-hand sides, ~80 for many."""
    memory_limit: float = 4e9
    """Bytes ``auto`` lets BiCGSTAB hold (6 fields of 72 C K bytes per node)."""
    check_every: int = 4
    """Plain iteration measures the residual every this many sweeps (a measuring sweep costs ~1.5x a plain one)."""
    dtype: str = "float32"
    """Arithmetic (and, with ``storage="fp32"``, storage) of the field: ``float32`` (default) or ``float64``."""
    storage: str = "fp32"
    """What the 18 densities are stored in between sweeps (``lighting.storage``): ``fp32`` (the field in ``dtype``)
    or ``fp16`` (scaled binary16, half the memory and traffic; arithmetic stays float32, one rounding per stored
    value and sweep). With fp16 ``auto`` never switches to BiCGSTAB (its Krylov vectors would be rounded to 11
    bits), it extrapolates instead."""
    initial: str = "unscattered"
    """Start from ``unscattered`` light (exact, one pass per direction: the iteration then only has to
    converge the scattered part, and skips the sweeps the direct beam needs to cross the grid) or ``zero``
    (the paper's start: only the boundary densities)."""
    keep_f: bool = False
    """Return the full directional field ``LBResult.f`` (memory: 19 x the energy density)."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tolerance) and 0 < self.tolerance < 1):
            raise ValueError(f"tolerance must be in (0, 1), got {self.tolerance}")
        if self.max_sweeps < 1:
            raise ValueError(f"max_sweeps must be >= 1, got {self.max_sweeps}")
        if self.solver not in SOLVERS:
            raise ValueError(f"solver must be one of {', '.join(SOLVERS)}, got {self.solver!r}")
        if self.initial not in ("unscattered", "zero"):
            raise ValueError(f"initial must be 'unscattered' or 'zero', got {self.initial!r}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"dtype must be float32 or float64, got {self.dtype!r}")
        if self.storage not in STORAGES:
            raise ValueError(f"storage must be one of {', '.join(STORAGES)}, got {self.storage!r}")
        if self.storage == "fp16" and self.dtype != "float32":
            raise ValueError(f"storage='fp16' computes in float32; it cannot be combined with dtype={self.dtype!r}")
        if self.storage == "fp16" and self.solver == "bicgstab":
            raise ValueError("storage='fp16' cannot be combined with solver='bicgstab': BiCGSTAB's Krylov vectors "
                             "and scalars need more than 11 bits; use solver='auto', 'iterate' or 'extrapolate'")
        if not (self.memory_limit > 0):
            raise ValueError(f"memory_limit must be > 0 bytes, got {self.memory_limit}")
        if self.check_every < 1:
            raise ValueError(f"check_every must be >= 1, got {self.check_every}")
        if self.switch_sweeps < 0:
            raise ValueError(f"switch_sweeps must be >= 0, got {self.switch_sweeps}")


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields explicitly
class LBResult:
    """Steady-state fields and the stats of the run."""

    energy_density: np.ndarray
    """(nx, ny, nz, K, C) float32/64: u = sum_i f_i per node, boundary condition k and channel c."""
    f: np.ndarray | None
    """(nx, ny, nz, 19, K, C) arriving densities f_i (f_0 = 0), if ``LBParams.keep_f``."""
    boundaries: tuple[str, ...]
    """Names of the K boundary conditions, in order."""
    iterations: int
    """Lattice sweeps (applications of the update) used, including the final check sweep."""
    residual: float
    """max over right-hand sides of ||f_{t+1} - f_t|| / ||f_t|| of the final sweep."""
    residuals: np.ndarray
    """(K, C) the same per right-hand side."""
    converged: bool
    seconds: float
    """Wall time of ``solve`` (setup, iteration and bookkeeping)."""
    solver: str
    """What ran: ``iterate``, ``bicgstab``, ``extrapolate``, or ``iterate+bicgstab`` / ``iterate+extrapolate`` (auto switched)."""
    mlups: float
    """Million node updates per second of the iteration, counting every right-hand side (node x rhs)."""
    nrhs: int
    inflow: np.ndarray
    """(K, C) float64: density entering through the boundary per sweep."""
    outflow: np.ndarray
    """(K, C) float64: density leaving the grid per sweep."""
    absorbed: np.ndarray
    """(K, C) float64: density absorbed (moved to f_0 and removed) per sweep; inflow = outflow + absorbed at steady state."""
    history: tuple[float, ...] = field(default=(), repr=False)
    """Max relative residual at each check of plain iteration and after each BiCGSTAB iteration (diagnostics)."""
    beam_direct: np.ndarray | None = field(default=None, repr=False)
    """(nx, ny, nz, K, C) float64: the exact unscattered beam at the node centres for beam right-hand sides (0 for
    the others; ``beam_fields(problem).direct``), or None without beams: what ``unscattered_energy`` gives for them."""
    beam_power: np.ndarray | None = field(default=None, repr=False)
    """(nx, ny, nz, K, C) float64: the power each cell takes out of a beam (``BeamFields.power``), or None."""
    once_scattered: np.ndarray | None = field(default=None, repr=False)
    """(nx, ny, nz, K, C): the lattice's first-order scattered field of the beams (their first-collision source
    carried along the lattice lines with attenuation only), part of ``energy_density``; None without beams.
    ``lighting.single_scatter`` replaces it by the exact one."""


# --------------------------------------------------------------------------- numba kernels


@njit(fastmath=True, cache=True)
def _pair_product(M, S, E):  # pragma: no cover - compiled
    """E = M @ S for M (9, 9) and S, E (9, n): one half of the parity-split collision.

    Written out for three output rows per pass: their 27 coefficients stay in (AVX-512) registers
    and each load of s_q feeds three FMAs. One core, n = 1216 (64^3, 57 rhs), operands in cache:
    ~140 GFLOP/s against ~37 for BLAS gemm through np.dot (packing the operands of such thin
    products costs it more than the arithmetic) and ~95 for one output row per pass.
    """
    n = S.shape[1]
    s0 = S[0]
    s1 = S[1]
    s2 = S[2]
    s3 = S[3]
    s4 = S[4]
    s5 = S[5]
    s6 = S[6]
    s7 = S[7]
    s8 = S[8]
    for p in range(0, NH, 3):
        ea = E[p]
        eb = E[p + 1]
        ec = E[p + 2]
        a0, a1, a2, a3, a4, a5, a6, a7, a8 = M[p, 0], M[p, 1], M[p, 2], M[p, 3], M[p, 4], M[p, 5], M[p, 6], M[p, 7], M[p, 8]
        b0, b1, b2, b3, b4, b5, b6, b7, b8 = (
            M[p + 1, 0], M[p + 1, 1], M[p + 1, 2], M[p + 1, 3], M[p + 1, 4], M[p + 1, 5], M[p + 1, 6], M[p + 1, 7], M[p + 1, 8]
        )
        c0, c1, c2, c3, c4, c5, c6, c7, c8 = (
            M[p + 2, 0], M[p + 2, 1], M[p + 2, 2], M[p + 2, 3], M[p + 2, 4], M[p + 2, 5], M[p + 2, 6], M[p + 2, 7], M[p + 2, 8]
        )
        for l in range(n):
            v0, v1, v2, v3, v4, v5, v6, v7, v8 = s0[l], s1[l], s2[l], s3[l], s4[l], s5[l], s6[l], s7[l], s8[l]
            ea[l] = a0 * v0 + a1 * v1 + a2 * v2 + a3 * v3 + a4 * v4 + a5 * v5 + a6 * v6 + a7 * v7 + a8 * v8
            eb[l] = b0 * v0 + b1 * v1 + b2 * v2 + b3 * v3 + b4 * v4 + b5 * v5 + b6 * v6 + b7 * v7 + b8 * v8
            ec[l] = c0 * v0 + c1 * v1 + c2 * v2 + c3 * v3 + c4 * v4 + c5 * v5 + c6 * v6 + c7 * v7 + c8 * v8


@njit(fastmath=True, cache=True)
def _add_squares(F, q):  # pragma: no cover - compiled
    """q[c] += sum over directions i of F[i, c]^2 (F (18, C, run), q (C, run) float64): mode 1's ||f||^2."""
    for i in range(F.shape[0]):
        for c in range(F.shape[1]):
            fi = F[i, c]
            qc = q[c]
            for l in range(fi.size):
                v = load(fi[l])
                qc[l] += v * v


@njit(fastmath=True, cache=True)
def _collide_pairs(F, c, l0, n, rexp, r0, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pexp, p0, cE, cO, one, use_src):  # pragma: no cover - compiled
    """E = AE S and O = AO D for channel c of the run [l0, l0 + n) of F (18, C, run), summed over materials.

    Omega depends only on the angle between directions, so it commutes with inversion c -> -c; over
    the opposite pairs (2p, 2p + 1) it splits into an even part acting on s = f_2p + f_2p+1 and an
    odd part acting on d = f_2p - f_2p+1 (``_parity_blocks``): two (9 x 9) @ (9 x n) products
    (``_pair_product``), half the multiply-adds of (18 x 18) @ (18 x n). The step density is folded
    into S = rho_p s and D = rho_p d (``rexp[m, k, r0 : r0 + n]``: rho_p on material m's nodes, 0
    elsewhere; k = 0 for the axial pairs p < 3, 1 for the non-axial ones, which have their own
    rho_d on the ``ordinates`` lattice), so geist2008 eq. (2) (f_0 removed, sec. 3) is f_2p + E_p +
    O_p and f_2p+1 + E_p - O_p, added by the caller on the way into the target slots. Materials
    have disjoint nodes, so their products add up. ``use_src``: the first-collision source of the
    beams is added too, s_i = coef_i(m, k) power(node, k), split the same way: ``pexp[m, c, p0 : p0 +
    n]`` is the power on material m's nodes (0 elsewhere; with one material the power itself),
    ``cE``, ``cO`` (nmat, C, 9, run) the parity parts of the coefficients tiled along the run
    (``_Operator``); ``one``: a single right-hand side, whose coefficients are constant along it.
    ``ae``, ``ao``: thread-local (9, 9) scratch; ``Sb, Db, Eb, Ob`` (9, n), ``extra`` >= 18 n values.
    """
    first = True
    for m in range(AE.shape[0]):
        if not has[m]:
            continue
        for p in range(NH):
            for q in range(NH):
                ae[p, q] = AE[m, c, p, q]
                ao[p, q] = AO[m, c, p, q]
        for p in range(NH):
            re = rexp[m, 0 if p < NAXIAL_PAIRS else 1, r0 : r0 + n]
            fa = F[2 * p, c, l0 : l0 + n]
            fb = F[2 * p + 1, c, l0 : l0 + n]
            sp = Sb[p]
            dp = Db[p]
            for l in range(n):
                r = re[l]
                va = load(fa[l])
                vb = load(fb[l])
                sp[l] = r * (va + vb)
                dp[l] = r * (va - vb)
        if first:
            _pair_product(ae, Sb, Eb)
            _pair_product(ao, Db, Ob)
            first = False
        else:
            # a further material: add its products (adding inside _pair_product instead ran 2x slower)
            Tb = extra[: 2 * NH * n].reshape((2 * NH, n))
            _pair_product(ae, Sb, Tb[:NH])
            _pair_product(ao, Db, Tb[NH:])
            for p in range(NH):
                ep = Eb[p]
                op = Ob[p]
                tp = Tb[p]
                tq = Tb[NH + p]
                for l in range(n):
                    ep[l] += tp[l]
                    op[l] += tq[l]
    if use_src:
        for m in range(AE.shape[0]):
            if not has[m]:
                continue
            pm = pexp[m, c, p0 : p0 + n]
            for p in range(NH):
                ep = Eb[p]
                op = Ob[p]
                if one:
                    ce1 = cE[m, c, p, 0]
                    co1 = cO[m, c, p, 0]
                    for l in range(n):
                        v = pm[l]
                        ep[l] += ce1 * v
                        op[l] += co1 * v
                else:
                    ce = cE[m, c, p, l0 : l0 + n]
                    co = cO[m, c, p, l0 : l0 + n]
                    for l in range(n):
                        v = pm[l]
                        ep[l] += ce[l] * v
                        op[l] += co[l] * v


@njit(parallel=True, fastmath=True, cache=True)
def _sweep_rows(f, out, rho, rhod, mat, A, AE, AO, mode, wt, part1, part2, pw, ct, cE, cO, use_src):  # pragma: no cover - compiled
    """One fused collision + push-streaming sweep over rows of nz * B values (long: many right-hand sides).

    Writes every non-inflow slot of ``out``. The layout of ``_Operator`` with one row per block (G = 1):
    f, out, wt : (nx, ny, 18, C, nz, B); rho, rhod : (nx, ny, nz) step density of the axial and the
    non-axial directions; mat : (nx, ny, nz) uint8;
    A : (nmat, C, 18, 18) moving block of the collision (A[m, c, i, j], ``collision.unit_moving_block``);
    AE, AO : (nmat, C, 9, 9) its even and odd parts over opposite pairs (``_parity_blocks``);
    part1, part2 : (nx, C, nz*B) float64 partial sums, per x-slab and (z, b).

    mode 0: out = T f.
    mode 1: out = T f, part1 += (out - f)^2 and part2 += f^2 (the residual of a plain sweep).
    mode 2: out = f - T f (the BiCGSTAB operator I - T), part1 += wt * out, part2 += out^2.
    ``use_src`` (modes 0 and 1 only): the beams' first-collision source is added (``_collide_pairs``;
    pw (nx, ny, C, nz*B) the power per node, ct (nmat, C, 18, nz*B) the coefficients, cE, cO their
    parity parts), so T f becomes the affine sweep T f + S s of a problem with a volume source.
    """
    nx, ny, nq, C, nz, B = f.shape
    nmat = A.shape[0]
    L = nz * B
    add_src = use_src and mode != 2
    # (x, y, direction, channel) -> the row's run of nz * B values, viewed once here: building these
    # views per row and direction (reshape, then index) cost ~1.1x on short rows (64^3, 1 rhs)
    f5 = f.reshape((nx, ny, nq, C, L))
    out5 = out.reshape((nx, ny, nq, C, L))
    wt5 = wt.reshape((nx, ny, nq, C, L))
    for x in prange(nx):
        # arithmetic in rho's dtype (float32 for both storages, ``lighting.storage``); H holds stored values
        H = np.empty((nq, C, L), dtype=f.dtype)
        buf = np.empty(nq * L, dtype=rho.dtype)
        prod = np.empty(nq * L, dtype=rho.dtype)
        extra = np.empty(nq * L, dtype=rho.dtype)
        acc = np.empty((3, L), dtype=rho.dtype)
        rexp = np.empty((nmat, 2, L), dtype=rho.dtype)
        pexp = np.zeros((nmat, C, L if add_src and nmat > 1 else 1), dtype=rho.dtype)
        has = np.zeros(nmat, dtype=np.bool_)
        ae = np.empty((NH, NH), dtype=rho.dtype)  # thread-local copies of AE[m, c], AO[m, c]
        ao = np.empty((NH, NH), dtype=rho.dtype)
        sgn = np.empty(2, dtype=rho.dtype)  # +1 / -1 in the field's dtype (a float64 sign would promote)
        sgn[0] = 1.0
        sgn[1] = -1.0
        for y in range(ny):
            rr = rho[x, y]
            rd = rhod[x, y]
            mm = mat[x, y]
            z0 = nz
            z1 = -1
            for m in range(nmat):
                has[m] = False
            for z in range(nz):
                if rr[z] > 0:
                    if z < z0:
                        z0 = z
                    z1 = z
                    has[mm[z]] = True
            F = f5[x, y]
            if mode == 1:
                _add_squares(F, part2[x])
            if z1 >= 0:
                # collision on the occupied z-range [z0, z1] of the row (zero-based views vectorize)
                l0 = z0 * B
                n = (z1 + 1 - z0) * B
                for m in range(nmat):
                    if has[m]:
                        re = rexp[m, 0, l0 : l0 + n]
                        rq = rexp[m, 1, l0 : l0 + n]
                        for zz in range(z1 + 1 - z0):
                            own = mm[z0 + zz] == m
                            v = rr[z0 + zz] if own else 0.0
                            vd = rd[z0 + zz] if own else 0.0
                            for b in range(B):
                                re[zz * B + b] = v
                                rq[zz * B + b] = vd
                        if add_src and nmat > 1:
                            for cc in range(C):
                                pm = pexp[m, cc, l0 : l0 + n]
                                pr = pw[x, y, cc, l0 : l0 + n]
                                for zz in range(z1 + 1 - z0):
                                    own = mm[z0 + zz] == m
                                    for b in range(B):
                                        pm[zz * B + b] = pr[zz * B + b] if own else 0.0
                if n >= _LONG_RUN_MIN:
                    # long runs: the parity-split products (``_collide_pairs``), added to the streamed values
                    # on the way into the target slots: the post-collision row is never stored
                    Sb = buf[: NH * n].reshape((NH, n))
                    Db = buf[NH * n : 2 * NH * n].reshape((NH, n))
                    Eb = prod[: NH * n].reshape((NH, n))
                    Ob = prod[NH * n : 2 * NH * n].reshape((NH, n))
                    for c in range(C):
                        if nmat == 1:
                            _collide_pairs(F, c, l0, n, rexp, l0, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pw[x, y : y + 1],
                                           l0, cE, cO, B == 1, add_src)
                        else:
                            _collide_pairs(F, c, l0, n, rexp, l0, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pexp, l0, cE, cO,
                                           B == 1, add_src)
                        # push-streaming f_i(r + c_i) = post_i(r), z-shift an offset in the row; the source
                        # run [lo, hi) splits into the pass-through head [lo, l0), the collided run
                        # [l0, l0 + n) and the pass-through tail [l0 + n, hi)
                        for i in range(nq):
                            tx = x + _CX[i]
                            ty = y + _CY[i]
                            if tx < 0 or tx >= nx or ty < 0 or ty >= ny:
                                continue  # the light leaves the grid
                            dz = _CZ[i]
                            lo = (-dz if dz < 0 else 0) * B
                            hi = (nz - dz if dz > 0 else nz) * B
                            d = dz * B
                            o = out5[tx, ty, i, c]
                            s = F[i, c]
                            p = i >> 1
                            ep = Eb[p]
                            op = Ob[p]
                            sg = sgn[i & 1]
                            if mode == 0:
                                # a plain sweep builds only the views it uses (1.2x at 64^3, 57 rhs)
                                a = lo
                                b1 = min(hi, l0)
                                if b1 > a:
                                    o[a + d : b1 + d] = s[a:b1]
                                a = max(lo, l0)
                                b1 = min(hi, l0 + n)
                                if b1 > a:
                                    oo = o[a + d : b1 + d]
                                    ss = s[a:b1]
                                    ee = ep[a - l0 : b1 - l0]
                                    od = op[a - l0 : b1 - l0]
                                    for l in range(b1 - a):
                                        oo[l] = convert(load(ss[l]) + ee[l] + sg * od[l], oo)
                                a = max(lo, l0 + n)
                                b1 = hi
                                if b1 > a:
                                    o[a + d : b1 + d] = s[a:b1]
                                continue
                            fo = f5[tx, ty, i, c]
                            wo = wt5[tx, ty, i, c]
                            q1 = part1[x, c]
                            q2 = part2[x, c]
                            a = lo
                            b1 = min(hi, l0)
                            if b1 > a:
                                _stream_piece(mode, True, o[a + d : b1 + d], s[a:b1], s[:0], s[:0], sg, fo[a + d : b1 + d],
                                              wo[a + d : b1 + d], q1[a + d : b1 + d], q2[a + d : b1 + d])
                            a = max(lo, l0)
                            b1 = min(hi, l0 + n)
                            if b1 > a:
                                _stream_piece(mode, True, o[a + d : b1 + d], s[a:b1], ep[a - l0 : b1 - l0],
                                              op[a - l0 : b1 - l0], sg, fo[a + d : b1 + d], wo[a + d : b1 + d],
                                              q1[a + d : b1 + d], q2[a + d : b1 + d])
                            a = max(lo, l0 + n)
                            b1 = hi
                            if b1 > a:
                                _stream_piece(mode, True, o[a + d : b1 + d], s[a:b1], s[:0], s[:0], sg, fo[a + d : b1 + d],
                                              wo[a + d : b1 + d], q1[a + d : b1 + d], q2[a + d : b1 + d])
                    continue  # streamed above
                else:
                    # short runs (the long-run path's per-call costs eat its gain: about even at n = 128,
                    # 1.2-1.7x slower at n = 64): three output directions per pass share each load of f_j
                    # (18 = 6 x 3)
                    a0 = acc[0, :n]
                    a1 = acc[1, :n]
                    a2 = acc[2, :n]
                    sc = buf[: nq * n].reshape((nq, n))  # rho_j f_j of one material and channel
                    for c in range(C):
                        for i in range(nq):
                            h = H[i, c]
                            fi = F[i, c]
                            for l in range(L):
                                h[l] = fi[l]
                        for m in range(nmat):
                            if not has[m]:
                                continue
                            for j in range(nq):
                                rj = rexp[m, 0 if j < 2 * NAXIAL_PAIRS else 1, l0 : l0 + n]
                                fj = F[j, c, l0 : l0 + n]
                                sj = sc[j]
                                for l in range(n):
                                    sj[l] = rj[l] * load(fj[l])
                            for i in range(0, nq, 3):
                                for l in range(n):
                                    a0[l] = 0.0
                                    a1[l] = 0.0
                                    a2[l] = 0.0
                                for j in range(nq):
                                    c0 = A[m, c, i, j]
                                    c1 = A[m, c, i + 1, j]
                                    c2 = A[m, c, i + 2, j]
                                    sj = sc[j]
                                    for l in range(n):
                                        v = sj[l]
                                        a0[l] += c0 * v
                                        a1[l] += c1 * v
                                        a2[l] += c2 * v
                                h0 = H[i, c, l0 : l0 + n]
                                h1 = H[i + 1, c, l0 : l0 + n]
                                h2 = H[i + 2, c, l0 : l0 + n]
                                # geist2008 eq. (2): f + sum_j A_ij rho_j f_j, f_0 removed (sec. 3)
                                for l in range(n):
                                    h0[l] = convert(load(h0[l]) + a0[l], h0)
                                    h1[l] = convert(load(h1[l]) + a1[l], h1)
                                    h2[l] = convert(load(h2[l]) + a2[l], h2)
                            if add_src:
                                pm = pexp[m, c, l0 : l0 + n] if nmat > 1 else pw[x, y, c, l0 : l0 + n]
                                for i in range(nq):
                                    h = H[i, c, l0 : l0 + n]
                                    ci = ct[m, c, i, l0 : l0 + n]
                                    for l in range(n):
                                        h[l] = convert(load(h[l]) + ci[l] * pm[l], h)
                src = H
            else:
                src = F  # empty row: pass-through
            # push-streaming: f_i(r + c_i) = post_i(r); z-shift is an offset in the row. The loops repeat
            # _stream_piece's on purpose: calling it per (direction, channel) here made short rows 1.25x slower
            for i in range(nq):
                tx = x + _CX[i]
                ty = y + _CY[i]
                dz = _CZ[i]
                if tx < 0 or tx >= nx or ty < 0 or ty >= ny:
                    continue
                lo = (-dz if dz < 0 else 0) * B
                hi = (nz - dz if dz > 0 else nz) * B
                d = dz * B
                n2 = hi - lo
                O = out5[tx, ty, i]
                if mode == 1:
                    Fo = f5[tx, ty, i]
                    for c in range(C):
                        o = O[c, lo + d : hi + d]
                        s = src[i, c, lo:hi]
                        fo = Fo[c, lo + d : hi + d]
                        rn = part1[x, c, lo + d : hi + d]
                        for l in range(n2):
                            v = s[l]
                            dd = load(v) - load(fo[l])
                            rn[l] += dd * dd
                            o[l] = v
                elif mode == 2:
                    Fo = f5[tx, ty, i]
                    Wo = wt5[tx, ty, i]
                    for c in range(C):
                        o = O[c, lo + d : hi + d]
                        s = src[i, c, lo:hi]
                        fo = Fo[c, lo + d : hi + d]
                        wo = Wo[c, lo + d : hi + d]
                        q1 = part1[x, c, lo + d : hi + d]
                        q2 = part2[x, c, lo + d : hi + d]
                        for l in range(n2):
                            w = load(fo[l]) - load(s[l])
                            o[l] = convert(w, o)
                            q1[l] += load(wo[l]) * w
                            q2[l] += w * w
                else:
                    for c in range(C):
                        o = O[c, lo + d : hi + d]
                        s = src[i, c, lo:hi]
                        for l in range(n2):
                            o[l] = s[l]


@njit(fastmath=True, cache=True)
def _stream_piece(mode, acc, o, s, e, od, sg, fo, wo, q1, q2):  # pragma: no cover - compiled
    """o = v (modes 0, 1) or fo - v (mode 2) with v = s + e + sg * od (``e`` empty: v = s); with ``acc``
    also the mode's sums: q1 += (o - fo)^2 (mode 1), q1 += wo * o and q2 += o^2 (mode 2)."""
    n = o.size
    if e.size == 0:
        if mode == 0 or (mode == 1 and not acc):
            for l in range(n):
                o[l] = s[l]
        elif mode == 1:
            for l in range(n):
                v = s[l]
                dd = load(v) - load(fo[l])
                q1[l] += dd * dd
                o[l] = v
        elif not acc:
            for l in range(n):
                o[l] = convert(load(fo[l]) - load(s[l]), o)
        else:
            for l in range(n):
                w = load(fo[l]) - load(s[l])
                o[l] = convert(w, o)
                q1[l] += load(wo[l]) * w
                q2[l] += w * w
    else:
        # the residual sums (mode 1) take the value as stored: with fp16 storage the rounded one
        if mode == 0 or (mode == 1 and not acc):
            for l in range(n):
                o[l] = convert(load(s[l]) + e[l] + sg * od[l], o)
        elif mode == 1:
            for l in range(n):
                v = convert(load(s[l]) + e[l] + sg * od[l], o)
                dd = load(v) - load(fo[l])
                q1[l] += dd * dd
                o[l] = v
        elif not acc:
            for l in range(n):
                o[l] = convert(load(fo[l]) - (load(s[l]) + e[l] + sg * od[l]), o)
        else:
            for l in range(n):
                w = load(fo[l]) - (load(s[l]) + e[l] + sg * od[l])
                o[l] = convert(w, o)
                q1[l] += load(wo[l]) * w
                q2[l] += w * w


@njit(fastmath=True, cache=True)
def _stream_segment(mode, o, s, fo, wo, q1, q2, a, b, d, limit, wrap_z, B, Lr, e, od, sg, l0, l1, save, slots):  # pragma: no cover - compiled
    """Push-stream the source run [a, b) of one direction and channel into the target block ``o`` at offset d.

    ``o, fo, wo, q1, q2`` are the target block's runs in out, f, wt, part1, part2 (only [0, limit)
    holds real rows; a plain sweep passes ``s`` for fo and wo); ``s`` is the source block's run. On
    [l0, l1) the source collided: the target gets the post-collision ``s + e + sg * od`` there, ``s``
    elsewhere (mode 2: ``fo`` minus that). A z-shift moves a row's last (first) node into the next
    (previous) row's first (last) slot of the flat block: those targets are inflow slots on the z
    faces, so they are saved here and put back, and then the mode 1/2 sums are taken over the
    target run in a second pass while it is in cache (subtracting a wrong term again would leave
    float round-off in a residual that can be ~1e-14). Without such slots (z-shift 0, or one row
    per block) the sums are taken in the same pass. ``save`` and ``slots`` are scratch for the
    saved values (G B) and the wrapped slots' offsets (G).
    """
    a = max(a, -d)
    b = min(b, limit - d)
    if b <= a:
        return
    ns = 0  # wrapped slots: the target offsets of the source's z-face nodes in [a, b)
    if wrap_z >= 0:
        for g in range(a // Lr, (b + Lr - 1) // Lr):
            t = g * Lr + wrap_z * B + d
            if t - d >= a and t - d + B <= b and t >= 0 and t + B <= limit:
                slots[ns] = t
                for k in range(B):
                    save[ns * B + k] = o[t + k]
                ns += 1
    acc = ns == 0
    none = e[:0]
    c1 = min(b, l0)
    if c1 > a:
        x0 = a + d
        x1 = c1 + d
        _stream_piece(mode, acc, o[x0:x1], s[a:c1], none, none, sg, fo[x0:x1], wo[x0:x1], q1[x0:x1], q2[x0:x1])
    c0 = max(a, l0)
    c1 = min(b, l1)
    if c1 > c0:
        x0 = c0 + d
        x1 = c1 + d
        _stream_piece(mode, acc, o[x0:x1], s[c0:c1], e[c0 - l0 : c1 - l0], od[c0 - l0 : c1 - l0], sg, fo[x0:x1],
                      wo[x0:x1], q1[x0:x1], q2[x0:x1])
    c0 = max(a, l1)
    if b > c0:
        x0 = c0 + d
        x1 = b + d
        _stream_piece(mode, acc, o[x0:x1], s[c0:b], none, none, sg, fo[x0:x1], wo[x0:x1], q1[x0:x1], q2[x0:x1])
    if ns == 0:
        return
    for w in range(ns):
        t = slots[w]
        for k in range(B):
            o[t + k] = save[w * B + k]
    if mode == 1:
        oo = o[a + d : b + d]
        ff = fo[a + d : b + d]
        r1 = q1[a + d : b + d]
        for l in range(b - a):
            dd = load(oo[l]) - load(ff[l])
            r1[l] += dd * dd
    elif mode == 2:
        oo = o[a + d : b + d]
        ww = wo[a + d : b + d]
        r1 = q1[a + d : b + d]
        r2 = q2[a + d : b + d]
        for l in range(b - a):
            w = load(oo[l])
            r1[l] += load(ww[l]) * w
            r2[l] += w * w


@njit(parallel=True, fastmath=True, cache=True)
def _sweep_blocks(f, out, rho, rhod, mat, AE, AO, mode, wt, part1, part2, pw, cE, cO, use_src):  # pragma: no cover - compiled
    """One fused collision + push-streaming sweep over blocks of G rows (short rows: few right-hand sides).

    Writes every non-inflow slot of ``out``. f, out, wt : (nx, NB, 18, C, G*nz, K), the block layout of ``_Operator``;
    rho, rhod : (nx, ny, nz) step density of the axial and the non-axial directions;
    mat : (nx, ny, nz) uint8; AE, AO : (nmat, C, 9, 9) the even and odd parts over opposite pairs of
    the unit-density moving block of Omega (``_parity_blocks``); part1, part2 : (nx, C, G*nz*K)
    float64 partial sums, per x-slab and position in the block's run.

    mode 0: out = T f.
    mode 1: out = T f, part1 += (out - f)^2 and part2 += f^2 (the residual of a plain sweep).
    mode 2: out = f - T f (the BiCGSTAB operator I - T), part1 += wt * out, part2 += out^2.
    ``use_src`` (modes 0 and 1 only): the beams' first-collision source is added (pw (nx, NB, C, G*nz*K)
    the power per node, cE, cO (nmat, C, 9, G*nz*K) the coefficients' parity parts; ``_collide_pairs``).
    """
    nx, nb, nq, C, gnz, B = f.shape
    ny = rho.shape[1]
    nz = rho.shape[2]
    G = gnz // nz
    Lr = nz * B  # one row's run
    R = G * Lr  # one block's run
    nmat = AE.shape[0]
    add_src = use_src and mode != 2
    f5 = f.reshape((nx, nb, nq, C, R))
    out5 = out.reshape((nx, nb, nq, C, R))
    wt5 = wt.reshape((nx, nb, nq, C, R))
    for x in prange(nx):
        # arithmetic in rho's dtype (float32 for both storages, ``lighting.storage``); ``save`` holds stored values
        buf = np.empty(2 * NH * R, dtype=rho.dtype)
        prod = np.empty(2 * NH * R, dtype=rho.dtype)
        extra = np.empty(2 * NH * R, dtype=rho.dtype)
        rexp = np.empty((nmat, 2, R), dtype=rho.dtype)
        pexp = np.zeros((nmat, C, R if add_src and nmat > 1 else 1), dtype=rho.dtype)
        has = np.zeros(nmat, dtype=np.bool_)
        save = np.empty(G * B, dtype=f.dtype)
        slots = np.empty(G, dtype=np.int64)
        ae = np.empty((NH, NH), dtype=rho.dtype)  # thread-local copies of AE[m, c], AO[m, c]
        ao = np.empty((NH, NH), dtype=rho.dtype)
        sgn = np.empty(2, dtype=rho.dtype)  # +1 / -1 in the field's dtype (a float64 sign would promote)
        sgn[0] = 1.0
        sgn[1] = -1.0
        for blk in range(nb):
            y0 = blk * G
            nrows = min(G, ny - y0)
            F = f5[x, blk]
            if mode == 1:
                _add_squares(F, part2[x])
            # occupied nodes j0 .. j1 - 1 of the block (flat (row, z) index): only they collide
            j0 = -1
            j1 = -1
            for m in range(nmat):
                has[m] = False
            for g in range(nrows):
                rr = rho[x, y0 + g]
                mm = mat[x, y0 + g]
                for z in range(nz):
                    if rr[z] > 0:
                        if j0 < 0:
                            j0 = g * nz + z
                        j1 = g * nz + z + 1
                        has[mm[z]] = True
            l0 = max(j0, 0) * B
            l1 = max(j1, 0) * B
            n = l1 - l0
            Sb = buf[: NH * n].reshape((NH, n))
            Db = buf[NH * n : 2 * NH * n].reshape((NH, n))
            Eb = prod[: NH * n].reshape((NH, n))
            Ob = prod[NH * n : 2 * NH * n].reshape((NH, n))
            if n > 0:
                for m in range(nmat):
                    re = rexp[m, 0]
                    rq = rexp[m, 1]
                    for j in range(j0, j1):
                        g = j // nz
                        z = j - g * nz
                        own = mat[x, y0 + g, z] == m
                        v = rho[x, y0 + g, z] if own else 0.0
                        vd = rhod[x, y0 + g, z] if own else 0.0
                        for b in range(B):
                            re[(j - j0) * B + b] = v
                            rq[(j - j0) * B + b] = vd
                        if add_src and nmat > 1:
                            for cc in range(C):
                                for b in range(B):
                                    pexp[m, cc, (j - j0) * B + b] = pw[x, blk, cc, j * B + b] if own else 0.0
            for c in range(C):
                if n > 0:
                    if nmat == 1:
                        _collide_pairs(F, c, l0, n, rexp, 0, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pw[x, blk : blk + 1], l0,
                                       cE, cO, B == 1, add_src)
                    else:
                        _collide_pairs(F, c, l0, n, rexp, 0, has, AE, AO, ae, ao, Sb, Db, Eb, Ob, extra, pexp, 0, cE, cO, B == 1,
                                       add_src)
                # push-streaming f_i(r + c_i) = post_i(r): within a block a y- and z-shift is one
                # offset of the flat run; the row that crosses into the next (previous) block goes there
                q1 = part1[x, c]
                q2 = part2[x, c]
                for i in range(nq):
                    tx = x + _CX[i]
                    if tx < 0 or tx >= nx:
                        continue  # the light leaves the grid
                    cy = _CY[i]
                    cz = _CZ[i]
                    wrap_z = -1 if cz == 0 else (nz - 1 if cz > 0 else 0)
                    s = F[i, c]
                    ep = Eb[i >> 1]
                    op = Ob[i >> 1]
                    sg = sgn[i & 1]
                    # rows whose target row is in this block
                    g0 = max(0, -cy)
                    g1 = min(nrows, nrows - cy)
                    if g1 > g0:
                        # a plain sweep passes s for the views it does not read (building them cost ~1.1x)
                        fo = f5[tx, blk, i, c] if mode != 0 else s
                        wo = wt5[tx, blk, i, c] if mode == 2 else s
                        _stream_segment(mode, out5[tx, blk, i, c], s, fo, wo, q1, q2, g0 * Lr, g1 * Lr,
                                        cy * Lr + cz * B, nrows * Lr, wrap_z, B, Lr, ep, op, sg, l0, l1, save, slots)
                    # the row whose target row is in the neighbouring block
                    tb = -1
                    if cy > 0 and nrows == G and blk + 1 < nb:
                        tb = blk + 1
                        a = (G - 1) * Lr
                        d = cz * B - (G - 1) * Lr
                        lim = min(G, ny - y0 - G) * Lr
                    elif cy < 0 and blk > 0:
                        tb = blk - 1
                        a = 0
                        d = (G - 1) * Lr + cz * B
                        lim = R
                    if tb >= 0:
                        fo = f5[tx, tb, i, c] if mode != 0 else s
                        wo = wt5[tx, tb, i, c] if mode == 2 else s
                        _stream_segment(mode, out5[tx, tb, i, c], s, fo, wo, q1, q2, a, a + Lr, d, lim, wrap_z, B, Lr,
                                        ep, op, sg, l0, l1, save, slots)


@njit(parallel=True, cache=True)
def _balance(f, rho, rhod, mat, A, sig_a, inflow_mask, wq, pw, cq, use_src):  # pragma: no cover - compiled
    """Per right-hand side (C, B): inflow, outflow and absorbed power of one sweep from f, in float64.

    f in the block layout of ``_Operator``: node (x, y, z) at f[x, y // G, :, :, (y % G) * nz + z].
    Power is ``sum_i wq_i f_i`` (wq_i = 1 / |c_i| on the ``ordinates`` lattice, 1 on ``geist2008``:
    ``power_weights``). With ``use_src`` the inflow includes the beams' first-collision source
    s_i = cq[m, c, i, b] pw[x, y // G, c, ((y % G) nz + z) B + b] (``_Operator``).
    """
    nx, nb, nq, C, gnz, B = f.shape
    ny = rho.shape[1]
    nz = rho.shape[2]
    G = gnz // nz
    inflow = np.zeros((nx, C, B))
    outflow = np.zeros((nx, C, B))
    absorbed = np.zeros((nx, C, B))
    for x in prange(nx):
        for y in range(ny):
            yb = y // G
            for z in range(nz):
                zb = (y % G) * nz + z
                p = rho[x, y, z]
                pd = rhod[x, y, z]
                m = mat[x, y, z]
                boundary = x == 0 or y == 0 or z == 0 or x == nx - 1 or y == ny - 1 or z == nz - 1
                for c in range(C):
                    for b in range(B):
                        tot = 0.0
                        for j in range(nq):
                            pj = p if j < 2 * NAXIAL_PAIRS else pd
                            tot += pj * wq[j] * load(f[x, yb, j, c, zb, b])
                        absorbed[x, c, b] += sig_a[m, c] * tot  # moved into f_0 (geist2008 eq. 5), then removed
                        pnode = float(pw[x, yb, c, zb * B + b]) if use_src else 0.0
                        if use_src:
                            for i in range(nq):
                                inflow[x, c, b] += wq[i] * cq[m, c, i, b] * pnode
                        if not boundary:
                            continue
                        for i in range(nq):
                            if inflow_mask[x, y, z, i]:
                                inflow[x, c, b] += wq[i] * load(f[x, yb, i, c, zb, b])
                            tx = x + _CX[i]
                            ty = y + _CY[i]
                            tz = z + _CZ[i]
                            if 0 <= tx < nx and 0 <= ty < ny and 0 <= tz < nz:
                                continue
                            h = float(load(f[x, yb, i, c, zb, b]))
                            if p > 0:
                                s = 0.0
                                for j in range(nq):
                                    pj = p if j < 2 * NAXIAL_PAIRS else pd
                                    s += A[m, c, i, j] * pj * load(f[x, yb, j, c, zb, b])
                                h += s
                            if use_src:
                                h += cq[m, c, i, b] * pnode
                            outflow[x, c, b] += wq[i] * h
    return inflow.sum(axis=0), outflow.sum(axis=0), absorbed.sum(axis=0)


@njit(parallel=True, cache=True)
def _once_scattered(f, att_a, att_d, power, cq, mat, ks, G):  # pragma: no cover - compiled
    """f[., q, ., ., k] for the beam right-hand sides ks: the first-collision source carried along each lattice line.

    The steady state of f_q(r) = f_q(r - c_q) att_q(r - c_q) + s_q(r - c_q) (0 in inflow slots), s_q =
    cq[m, c, q, k] power[r, k, c], built in the order of the line (one pass per direction, exact for
    light scattered once); att_a / att_d: the per-step survival of axial / non-axial steps (nx, ny, nz, C).
    f in the block layout of ``_Operator``; directions in parallel (each writes only its own slots).
    """
    nx, ny, nz, C = att_a.shape
    for q in prange(NQ):
        cx, cy, cz = _CX[q], _CY[q], _CZ[q]
        att = att_a if q < 2 * NAXIAL_PAIRS else att_d
        for a in range(nx):
            x = a if cx >= 0 else nx - 1 - a
            for b in range(ny):
                y = b if cy >= 0 else ny - 1 - b
                for e in range(nz):
                    z = e if cz >= 0 else nz - 1 - e
                    ux, uy, uz = x - cx, y - cy, z - cz
                    if ux < 0 or ux >= nx or uy < 0 or uy >= ny or uz < 0 or uz >= nz:
                        for c in range(C):
                            for k in ks:
                                f[x, y // G, q, c, (y % G) * nz + z, k] = 0.0
                    else:
                        m = mat[ux, uy, uz]
                        for c in range(C):
                            for k in ks:
                                v = load(f[ux, uy // G, q, c, (uy % G) * nz + uz, k]) * att[ux, uy, uz, c]
                                f[x, y // G, q, c, (y % G) * nz + z, k] = convert(v + cq[m, c, q, k] * power[ux, uy, uz, k, c], f)


@njit(parallel=True, fastmath=True, cache=True)
def _dot(a, b, part):  # pragma: no cover - compiled
    """part[x, c, l] = sum over (y, i) of a*b; a, b : (nx, M, C, L)."""
    nx, M, C, L = a.shape
    for x in prange(nx):
        for c in range(C):
            p = part[x, c]
            for l in range(L):
                p[l] = 0.0
            for k in range(M):
                u = a[x, k, c]
                v = b[x, k, c]
                for l in range(L):
                    p[l] += u[l] * v[l]


@njit(parallel=True, fastmath=True, cache=True)
def _axpy_norm(y, alpha, x_, part):  # pragma: no cover - compiled
    """y <- y + alpha * x (alpha per (c, l)), with partial sums of y.y."""
    nx, M, C, L = y.shape
    for x in prange(nx):
        for c in range(C):
            q = part[x, c]
            al = alpha[c]
            for l in range(L):
                q[l] = 0.0
            for k in range(M):
                yy = y[x, k, c]
                xx = x_[x, k, c]
                for l in range(L):
                    w = yy[l] + al[l] * xx[l]
                    yy[l] = w
                    q[l] += w * w


@njit(parallel=True, fastmath=True, cache=True)
def _update_xr(xv, alpha, p, omega, r, t, rhat, part_xx, part_rr, part_hr):  # pragma: no cover - compiled
    """x <- x + alpha p + omega s and r <- s - omega t (r holds s), with partial sums of x.x, r.r, rhat.r."""
    nx, M, C, L = xv.shape
    for x in prange(nx):
        for c in range(C):
            q1 = part_xx[x, c]
            q2 = part_rr[x, c]
            q3 = part_hr[x, c]
            al = alpha[c]
            om = omega[c]
            for l in range(L):
                q1[l] = 0.0
                q2[l] = 0.0
                q3[l] = 0.0
            for k in range(M):
                xx = xv[x, k, c]
                pp = p[x, k, c]
                rr = r[x, k, c]
                tt = t[x, k, c]
                hh = rhat[x, k, c]
                for l in range(L):
                    sv = rr[l]
                    w = xx[l] + al[l] * pp[l] + om[l] * sv
                    xx[l] = w
                    q1[l] += w * w
                    u = sv - om[l] * tt[l]
                    rr[l] = u
                    q2[l] += u * u
                    q3[l] += hh[l] * u


@njit(parallel=True, fastmath=True, cache=True)
def _extrapolate(f, prev, factor):  # pragma: no cover - compiled
    """f <- f + factor (f - prev), factor per (c, l)."""
    nx, M, C, L = f.shape
    for x in prange(nx):
        for c in range(C):
            fa = factor[c]
            for k in range(M):
                ff = f[x, k, c]
                pp = prev[x, k, c]
                for l in range(L):
                    v = load(ff[l])
                    ff[l] = convert(v + fa[l] * (v - load(pp[l])), ff)


@njit(parallel=True, fastmath=True, cache=True)
def _p_update(p, r, v, beta, omega):  # pragma: no cover - compiled
    """p <- r + beta (p - omega v)."""
    nx, M, C, L = p.shape
    for x in prange(nx):
        for c in range(C):
            be = beta[c]
            om = omega[c]
            for k in range(M):
                pp = p[x, k, c]
                rr = r[x, k, c]
                vv = v[x, k, c]
                for l in range(L):
                    pp[l] = rr[l] + be[l] * (pp[l] - om[l] * vv[l])


# --------------------------------------------------------------------------- operator in the row layout


def _safe_div(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a / b, 0 where b == 0 (both finite: callers check the field for non-finite values first)."""
    return np.divide(a, b, out=np.zeros(np.broadcast(a, b).shape), where=b != 0)


class _Operator:
    """The problem's arrays in the kernel's block layout ``(nx, NB, 18, C, G * nz, K)``.

    Rows of G consecutive y (the last block padded with zero rows) share one contiguous run of
    G nz K values per direction and channel: node (x, y, z) is at ``[x, y // G, :, :, (y % G) nz + z]``.
    G = ``_BLOCK_VALUES`` // (nz K), at least 1 and at most ny: with many right-hand sides a block is one
    row, with few the kernel's loops still run over about ``_BLOCK_VALUES`` values.
    """

    def __init__(self, problem: LBProblem, dtype: str, storage: str = "fp32") -> None:
        self.dtype = np.dtype(dtype)  # arithmetic (and every array but the state)
        self.storage = storage_dtype(storage, dtype)  # the state: ``lighting.storage``
        nx, ny, nz = problem.shape
        self.nx, self.ny, self.nz = nx, ny, nz
        self.C = problem.channels
        self.K = len(problem.boundaries)
        row = nz * self.K
        self.long_rows = row >= _ROW_KERNEL_MIN  # swept row by row (``_sweep_rows``), G = 1
        self.G = 1 if self.long_rows else max(1, min(ny, _BLOCK_VALUES // row))
        self.NB = -(-ny // self.G)
        self.L = self.G * nz * self.K  # a block's run
        self.state_shape = (nx, self.NB, NQ, self.C, self.G * nz, self.K)
        self.lattice = problem.lattice
        # always a writable copy: the problem's read-only array would be another numba type (a second compile of
        # every kernel for float64, which passed it through)
        self.rho = np.array(problem.density, dtype=self.dtype, order="C")
        # the non-axial steps' own density on the ordinates lattice (collision: rho_d = 1 - (1 - rho)^sqrt2)
        self.rhod = (np.ascontiguousarray(diagonal_density(problem.density), dtype=self.dtype)
                     if problem.lattice == "ordinates" else self.rho)
        self.wq = power_weights(problem.lattice)
        self.mat = np.zeros(problem.shape, np.uint8)
        media = [problem.medium]
        if problem.brown_mask is not None and problem.brown_mask.any():
            self.mat[problem.brown_mask] = 1
            assert problem.brown_medium is not None  # LBProblem.__post_init__ defaults it to brown(medium)
            media.append(problem.brown_medium)
        self.media = tuple(media)
        A64 = np.stack([unit_moving_block(m, problem.lattice) for m in media])
        self.A = np.ascontiguousarray(A64, dtype=self.dtype)
        self.AE, self.AO = (np.ascontiguousarray(b, dtype=self.dtype) for b in _parity_blocks(A64))
        self.sig_a = np.array([m.sigma_a for m in media], dtype=np.float64)
        self.bnd = np.array([b.inflow for b in problem.boundaries], dtype=np.float64).T  # (18, K)
        # inflow slot (r, i): the upstream node r - c_i is outside the grid
        idx = np.indices(problem.shape)
        self.inflow_mask = np.zeros((nx, ny, nz, NQ), bool)
        for q in range(NQ):
            c = DIRECTIONS[q + 1]
            up = [idx[a] - c[a] for a in range(3)]
            self.inflow_mask[..., q] = np.any([(u < 0) | (u >= n) for u, n in zip(up, problem.shape)], axis=0)
        self._parts = [np.zeros((nx, self.C, self.L)) for _ in range(3)]
        # beams: the exact unscattered beam at every node and the power each cell takes out of it, in the
        # kernel's run layout (nx, NB, C, G nz K); the source of direction i is cq[m, c, i, k] x that power,
        # built on the fly by the kernels (``_collide_pairs``) instead of stored as a field of 18 directions
        self.beam_rhs = np.array([b.beam is not None for b in problem.boundaries])
        self.beams = beam_fields(problem) if self.beam_rhs.any() else None
        if self.beams is None:
            self.pw = np.zeros((nx, self.NB, 1, 1), self.dtype)  # never read (use_src False); indexable per block
            self.cq = np.zeros((1, 1, NQ, 1))
        else:
            pw = self._padded(self.beams.power)  # (nx, NB, G, nz, K, C)
            self.pw = np.ascontiguousarray(pw.transpose(0, 1, 5, 2, 3, 4).reshape(nx, self.NB, self.C, self.L), dtype=self.dtype)
            self.cq = np.ascontiguousarray(self.beams.coef.transpose(0, 1, 3, 2))  # (nmat, C, 18, K)
        ct = np.tile(self.cq, (1, 1, 1, self.G * nz if self.beams is not None else 1))
        self.ct = np.ascontiguousarray(ct, dtype=self.dtype)
        self.cE = np.ascontiguousarray(0.5 * (ct[:, :, 0::2] + ct[:, :, 1::2]), dtype=self.dtype)
        self.cO = np.ascontiguousarray(0.5 * (ct[:, :, 0::2] - ct[:, :, 1::2]), dtype=self.dtype)

    @property
    def use_src(self) -> bool:
        return self.beams is not None

    @property
    def nodes(self) -> int:
        return self.nx * self.ny * self.nz

    @property
    def field_bytes(self) -> int:
        return int(np.prod(self.state_shape)) * self.storage.itemsize

    def zeros(self) -> np.ndarray:
        return np.zeros(self.state_shape, self.storage)  # 0 is all-zero bits in binary16 too

    def _nodes(self, f: np.ndarray) -> np.ndarray:
        """View (nx, NB, G, 18, C, nz, K) of a state: axes 1 and 2 are y // G and y % G."""
        return f.reshape(self.nx, self.NB, NQ, self.C, self.G, self.nz, self.K).transpose(0, 1, 4, 2, 3, 5, 6)

    def _rows(self, a: np.ndarray) -> np.ndarray:
        """(nx, NB * G, ...) per-node values -> (nx, ny, ...) (the padding rows dropped)."""
        return a.reshape((self.nx, self.NB * self.G) + a.shape[3:])[:, : self.ny]

    def _padded(self, a: np.ndarray) -> np.ndarray:
        """(nx, ny, ...) -> (nx, NB, G, ...), the padding rows zero (False)."""
        full = np.zeros((self.nx, self.NB * self.G) + a.shape[2:], a.dtype)
        full[:, : self.ny] = a
        return full.reshape((self.nx, self.NB, self.G) + a.shape[2:])

    def set_inflow(self, f: np.ndarray, *, zero: bool = False) -> None:
        """Write the boundary densities (or zeros) into the inflow slots of ``f``."""
        nodes = self._nodes(f)
        mask = self._padded(self.inflow_mask)  # (nx, NB, G, nz, 18)
        for q in range(NQ):
            view = np.moveaxis(nodes[:, :, :, q], 3, 4)  # (nx, NB, G, nz, C, K), a view of f
            view[mask[..., q]] = 0.0 if zero else to_storage(self.bnd[q], self.storage)

    def initial(self) -> np.ndarray:
        f = self.zeros()
        self.set_inflow(f)
        return f

    def unscattered(self, problem: LBProblem) -> np.ndarray:
        """The start of the iteration in the kernel layout: for boundary inflow the never-scattered field,
        f_q = b_q t_q (``unscattered_energy``), inflow slots = b; for a beam the once-scattered light, its
        first-collision source carried along each lattice line without further scattering (one ordered
        pass per direction, exact for that order of scattering)."""
        f = self.zeros()
        nodes = self._nodes(f)
        for q, t in _transmittances(problem, self.bnd.any(axis=1), self.dtype):
            # t (nx, ny, nz, C) -> (nx, NB, G, C, nz, K)
            nodes[:, :, :, q] = to_storage(self._padded(t).transpose(0, 1, 2, 4, 3)[..., None] * self.bnd[q].astype(self.dtype),
                                           self.storage)
        if self.beams is not None:
            att_a, att_d = _attenuations(problem, np.float64)
            _once_scattered(f, att_a, att_d, self.beams.power, self.cq, self.mat, np.nonzero(self.beam_rhs)[0], self.G)
        return f

    def balance(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-sweep (inflow, outflow, absorbed) power of state f, each (C, K) float64 (``_balance``)."""
        return _balance(f, self.rho, self.rhod, self.mat, self.A, self.sig_a, self.inflow_mask, self.wq, self.pw, self.cq,
                        self.use_src)

    def to_row(self, f19: np.ndarray) -> np.ndarray:
        """(nx, ny, nz, 19, K, C) -> the kernel layout (f_0 dropped)."""
        f = self.zeros()
        self._nodes(f)[...] = to_storage(self._padded(np.asarray(f19)[..., 1:, :, :].transpose(0, 1, 3, 5, 2, 4)), self.storage)
        return f

    def from_row(self, f: np.ndarray) -> np.ndarray:
        """The kernel layout -> (nx, ny, nz, 19, K, C) with f_0 = 0."""
        full = np.zeros((self.nx, self.ny, self.nz, 19, self.K, self.C), self.dtype)
        full[..., 1:, :, :] = from_storage(self._rows(self._nodes(f)).transpose(0, 1, 4, 2, 5, 3), self.dtype)
        return full

    def energy(self, f: np.ndarray) -> np.ndarray:
        """Energy density u = sum_i f_i per node and right-hand side, (nx, ny, nz, K, C)."""
        if f.dtype == self.dtype:
            u = f.sum(axis=2)
        else:  # stored in 16 bits: widen one direction at a time (a float32 copy of the field would double it)
            u = from_storage(f[:, :, 0], self.dtype)
            for q in range(1, NQ):
                u += from_storage(f[:, :, q], self.dtype)
        u = u.reshape(self.nx, self.NB, self.C, self.G, self.nz, self.K)
        return np.ascontiguousarray(self._rows(u.transpose(0, 1, 3, 4, 5, 2)))

    def vec(self, a: np.ndarray) -> np.ndarray:
        return a.reshape(self.nx, self.NB * NQ, self.C, self.L)

    def reduce(self, part: np.ndarray) -> np.ndarray:
        """(nx, C, L) partial sums -> (C, K)."""
        return part.sum(axis=0).reshape(self.C, self.G * self.nz, self.K).sum(axis=1)

    def expand(self, s: np.ndarray) -> np.ndarray:
        """(C, K) per-rhs scalars -> (C, L) for the flattened (y % G, z, k) run."""
        return np.ascontiguousarray(np.tile(s, (1, self.G * self.nz)), dtype=self.dtype)

    def _kernel(self, f, out, mode, wt, p1, p2) -> None:
        if self.long_rows:
            _sweep_rows(f, out, self.rho, self.rhod, self.mat, self.A, self.AE, self.AO, mode, wt, p1, p2, self.pw, self.ct,
                        self.cE, self.cO, self.use_src)
        else:
            _sweep_blocks(f, out, self.rho, self.rhod, self.mat, self.AE, self.AO, mode, wt, p1, p2, self.pw, self.cE, self.cO,
                          self.use_src)

    @overload
    def sweep(self, f: np.ndarray, out: np.ndarray, *, residual: Literal[True]) -> np.ndarray: ...
    @overload
    def sweep(self, f: np.ndarray, out: np.ndarray, *, residual: bool) -> np.ndarray | None: ...
    def sweep(self, f: np.ndarray, out: np.ndarray, *, residual: bool) -> np.ndarray | None:
        """out <- one lattice update of f (inflow slots of out untouched); per-rhs relative residual if asked."""
        p1, p2 = self._parts[0], self._parts[1]
        if residual:
            p1[:] = 0.0
            p2[:] = 0.0
        self._kernel(f, out, 1 if residual else 0, f, p1, p2)
        if not residual:
            return None
        num, den = self.reduce(p1), self.reduce(p2)
        return np.sqrt(np.where(den > 0, _safe_div(num, den), np.where(num > 0, np.inf, 0.0)))

    def apply(self, v: np.ndarray, out: np.ndarray, wt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """out <- (I - T) v for a vector with zero inflow slots; returns per-rhs (wt . out, out . out)."""
        p1, p2 = self._parts[0], self._parts[1]
        p1[:] = 0.0
        p2[:] = 0.0
        self._kernel(v, out, 2, wt, p1, p2)
        return self.reduce(p1), self.reduce(p2)

    def dot(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        _dot(self.vec(a), self.vec(b), self._parts[0])
        return self.reduce(self._parts[0])


# --------------------------------------------------------------------------- solvers


def _iterate(
    op: _Operator,
    f: np.ndarray,
    tol: float,
    budget: int,
    every: int,
    history: list,
    switch_after: int | None,
    *,
    extrapolate: bool = False,
    warmup: int | None = None,
):
    """Plain sweeps from f, residual measured every ``every`` sweeps.

    Returns (f, sweeps, residuals (C, K), stopped_to_switch).

    The warm-up (default: the longest edge, at least 16 sweeps) is the time
    light needs to cross the grid, during which the residual falls slowly
    whatever the medium. After it:

    * ``switch_after``: stop when the contraction rate q measured over the
      last >= 8 sweeps predicts more than ``switch_after`` sweeps to go.
    * ``extrapolate``: measure the residual every sweep; when three consecutive
      per-sweep ratios q of a right-hand side agree to 1e-3, jump that
      right-hand side to ``f + (f - f_prev) q / (1 - q)``, the sum of the
      remaining geometric series of its slowest mode (Lyusternik
      extrapolation). The stopping test is unchanged, so a poor jump can only
      cost sweeps, never fake convergence.
    """
    out = f.copy()
    res = np.full((op.C, op.K), np.inf)
    warm = max(16, op.nx, op.ny, op.nz) if warmup is None else warmup
    checks: list[tuple[int, float]] = []
    prev_res: np.ndarray | None = None
    ratios: list[np.ndarray] = []
    allowed = np.ones((op.C, op.K), bool)  # right-hand sides extrapolation may still jump
    jumped: np.ndarray | None = None  # residual just before the last jump
    for t in range(1, budget + 1):
        every_sweep = extrapolate and t >= warm
        check = every_sweep or t % every == 0 or t == budget
        r = op.sweep(f, out, residual=check)
        f, out = out, f  # f = f_t, out = f_{t-1}
        if not check:
            prev_res = None
            continue
        assert r is not None  # swept with residual=check
        res = r
        if not np.all(np.isfinite(res)):
            raise LBNumericalError(
                "the lattice field became non-finite"
                + (" after an extrapolation jump; use the solver 'iterate' or 'bicgstab'" if extrapolate else "")
                + f" (sweep {t}). This is a bug if it happens with plain iteration: please report it with the input."
            )
        now = float(res.max())
        history.append(now)
        checks.append((t, now))
        if now < tol:
            return f, t, res, False
        if every_sweep:
            if jumped is not None:
                # a jump that did not lower the residual says the one-mode model is wrong here: stop jumping
                allowed &= ~(res > jumped)
                jumped = None
            if prev_res is not None:
                ratios = [*ratios[-2:], _safe_div(res, prev_res)]
            prev_res = res
            if len(ratios) == 3:
                q = np.stack(ratios)
                ok = allowed & (q.max(axis=0) < 1.0) & (q.min(axis=0) > 0.0) & (q.max(axis=0) - q.min(axis=0) < 1e-3)
                if ok.any():
                    qq = np.minimum(q[-1], _MAX_EXTRAPOLATION_Q)
                    _extrapolate(op.vec(f), op.vec(out), op.expand(np.where(ok, qq / (1.0 - qq), 0.0)))
                    ratios, prev_res, jumped = [], None, np.where(ok, res, np.inf)
        if switch_after is not None and t >= warm:
            back = [c for c in checks if c[0] <= t - 8]
            if back:
                t_prev, prev = back[-1]
                q1 = (now / prev) ** (1.0 / (t - t_prev)) if prev > 0 else 0.0
                if q1 >= 1.0 or math.log(tol / now) / math.log(q1) > switch_after:
                    return f, t, res, True
    return f, budget, res, False


def _bicgstab(op: _Operator, x: np.ndarray, tol: float, budget: int, history: list):
    """BiCGSTAB on (I - T) x = beta for all right-hand sides in lock-step (van der Vorst 1992).

    ``x`` holds beta in its inflow slots; every Krylov vector has zero inflow
    slots, so the kernel (which never writes inflow slots) applies T to them
    directly. Returns (x, sweeps, converged_flags (C, K)).
    """
    C, K = op.C, op.K
    sweeps = 0
    r = op.zeros()
    op.sweep(x, r, residual=False)  # T x (+ propagation of the inflow held in x)
    sweeps += 1
    r -= x
    op.set_inflow(r, zero=True)  # r = T x + beta - x: zero in the inflow slots
    rhat = r.copy()
    p = op.zeros()
    v = op.zeros()
    t = op.zeros()
    ones = np.ones((C, K))
    rho_old, alpha, omega_ = ones.copy(), ones.copy(), ones.copy()
    rr = op.dot(r, r)
    xx = op.dot(x, x)
    hr = rr.copy()
    done = np.sqrt(_safe_div(rr, xx)) < tol
    V = op.vec
    pa, pb, pc = op._parts
    while sweeps + 2 <= budget and not done.all():
        rho_new = hr
        beta = _safe_div(rho_new, rho_old) * _safe_div(alpha, omega_)
        beta[done] = 0.0
        _p_update(V(p), V(r), V(v), op.expand(beta), op.expand(omega_))
        hv, _ = op.apply(p, v, rhat)  # v = (I - T) p, rhat . v
        sweeps += 1
        alpha = _safe_div(rho_new, hv)
        alpha[done] = 0.0
        _axpy_norm(V(r), op.expand(-alpha), V(v), pa)  # r <- s = r - alpha v
        ts, tt = op.apply(r, t, r)  # t = (I - T) s, t . s, t . t
        sweeps += 1
        omega_ = _safe_div(ts, tt)
        omega_[done] = 0.0
        # x <- x + alpha p + omega s, r <- s - omega t
        _update_xr(V(x), op.expand(alpha), V(p), op.expand(omega_), V(r), V(t), V(rhat), pa, pb, pc)
        xx, rr, hr = op.reduce(pa), op.reduce(pb), op.reduce(pc)
        rho_old = rho_new
        res = np.sqrt(_safe_div(rr, xx))
        done |= res < tol
        history.append(float(res.max()))
        # breakdown (rhat . r ~ 0 or omega = 0): restart that right-hand side with rhat = r
        bad = ~done & ((np.abs(hr) <= 1e-12 * rr) | (omega_ == 0.0))
        for c, k in zip(*np.nonzero(bad)):
            rhat[:, :, :, c, :, k] = r[:, :, :, c, :, k]
            p[:, :, :, c, :, k] = 0.0
            v[:, :, :, c, :, k] = 0.0
            hr[c, k] = rr[c, k]
            rho_old[c, k] = alpha[c, k] = omega_[c, k] = 1.0
    return x, sweeps, done


def solve(problem: LBProblem, params: LBParams = LBParams()) -> LBResult:
    """Steady state of the lattice for every boundary condition and channel of ``problem``.

    Returns energy density u = sum_i f_i per node (and f if asked), the
    residual, sweeps, timing and the per-sweep energy balance; see the module
    docstring for the solvers and units.
    """
    t0 = time.perf_counter()
    op = _Operator(problem, params.dtype, params.storage)
    nrhs = op.C * op.K
    tol = params.tolerance
    history: list[float] = []
    f = op.unscattered(problem) if params.initial == "unscattered" else op.initial()
    once = None
    if op.beams is not None:  # the lattice's once-scattered light: the unscattered start for a beam
        once = op.energy(f if params.initial == "unscattered" else op.unscattered(problem))
    sweeps = 0
    used: list[str] = []
    t_loop = time.perf_counter()
    res = np.full((op.C, op.K), np.inf)
    switched = False
    if params.solver in ("iterate", "auto", "extrapolate"):
        switch = params.switch_sweeps if params.solver == "auto" else None
        extra = params.solver == "extrapolate"
        f, n, res, switched = _iterate(op, f, tol, params.max_sweeps, params.check_every, history, switch, extrapolate=extra)
        sweeps += n
        used.append("extrapolate" if extra else "iterate")
    krylov = params.solver == "bicgstab"
    if switched:  # auto, and plain iteration is slow
        krylov = 6 * op.field_bytes <= params.memory_limit and params.storage == "fp32"
        log.info("lb solve: plain sweeps converge slowly after %d (residual %.2e); switching to %s", sweeps,
                 float(res.max()), "BiCGSTAB" if krylov else "extrapolated sweeps (BiCGSTAB would not fit or needs fp32)")
        if not krylov:
            f, n, res, _ = _iterate(
                op, f, tol, params.max_sweeps - sweeps, params.check_every, history, None, extrapolate=True, warmup=0
            )
            sweeps += n
            used.append("extrapolate")
    if krylov:
        used.append("bicgstab")
        for _attempt in range(4):
            budget = params.max_sweeps - sweeps - 1
            if budget < 3:
                break
            f, n, _ = _bicgstab(op, f, tol, budget, history)
            sweeps += n
            # the reported residual is always that of a plain sweep from the result
            out = f.copy()
            res = op.sweep(f, out, residual=True)
            sweeps += 1
            f = out
            if res.max() < tol:
                break
        if not np.all(np.isfinite(res)):  # max_sweeps leaves no room for a BiCGSTAB step: plain sweeps
            f, n, res, _ = _iterate(op, f, tol, max(params.max_sweeps - sweeps, 1), params.check_every, history, None)
            sweeps += n
            used.append("iterate")
    loop_seconds = time.perf_counter() - t_loop
    log.debug("lb solve: %s nodes x %d rhs, %s, %d sweeps, residual %.2e (tolerance %.1e), %.2f s", f"{op.nodes:,}", nrhs,
              "+".join(used), sweeps, float(res.max()), tol, loop_seconds)
    if not np.all(np.isfinite(res)):
        raise LBNumericalError(f"the lattice solve ended with a non-finite residual (solver {'+'.join(used)}); "
                               "use the solver 'iterate', and please report the input.")
    inflow, outflow, absorbed = op.balance(f)
    energy = op.energy(f)  # (nx, ny, nz, K, C)
    if op.beams is not None:  # a beam's lattice field is its scattered light: add the exact unscattered beam
        energy += op.beams.direct.astype(energy.dtype)
    full = op.from_row(f) if params.keep_f else None
    return LBResult(
        energy_density=energy,
        f=full,
        boundaries=tuple(b.name for b in problem.boundaries),
        iterations=sweeps,
        residual=float(res.max()),
        residuals=res.T.copy(),
        converged=bool(res.max() < tol),
        seconds=time.perf_counter() - t0,
        solver="+".join(used),
        mlups=op.nodes * nrhs * sweeps / max(loop_seconds, 1e-12) / 1e6,
        nrhs=nrhs,
        inflow=inflow.T.copy(),
        outflow=outflow.T.copy(),
        absorbed=absorbed.T.copy(),
        history=tuple(history),
        beam_direct=None if op.beams is None else op.beams.direct,
        beam_power=None if op.beams is None else op.beams.power,
        once_scattered=once,
    )


# --------------------------------------------------------------------------- unscattered light in one pass


@njit(cache=True)
def _transmit(att, cx, cy, cz, out):  # pragma: no cover - compiled
    """out[r, c] = density arriving at r along c = (cx, cy, cz) per unit inflow, never scattered.

    The steady state of ``f_i(r) = f_i(r - c_i) * att(r - c_i)`` with f_i = 1
    in inflow slots, filled in the order of the beam so every upstream value
    is final when it is read (one pass, exact; no iteration).
    """
    nx, ny, nz, C = att.shape
    for a in range(nx):
        x = a if cx >= 0 else nx - 1 - a
        for b in range(ny):
            y = b if cy >= 0 else ny - 1 - b
            for e in range(nz):
                z = e if cz >= 0 else nz - 1 - e
                ux, uy, uz = x - cx, y - cy, z - cz
                if ux < 0 or ux >= nx or uy < 0 or uy >= ny or uz < 0 or uz >= nz:
                    for c in range(C):
                        out[x, y, z, c] = 1.0
                else:
                    for c in range(C):
                        out[x, y, z, c] = out[ux, uy, uz, c] * att[ux, uy, uz, c]


#: Fields of 18 float32 directions (72 bytes per node and right-hand side) plain iteration holds: the
#: state and its update, plus the outputs and temporaries of the bake (~0.3 field).
PLAIN_ITERATION_FIELDS = 2.3


def memory_bytes(shape, nrhs: int, fields: float = PLAIN_ITERATION_FIELDS, value_bytes: int = 4) -> float:
    """Bytes a solve on a grid of ``shape`` with ``nrhs`` right-hand sides holds (``fields`` fields of
    ``value_bytes`` per density: 4 for ``storage="fp32"``, 2 for ``"fp16"``)."""
    return float(np.prod(shape)) * nrhs * NQ * value_bytes * fields


def unscattered_energy(problem: LBProblem, dtype: str = "float32") -> np.ndarray:
    """Energy density u_unscattered (nx, ny, nz, K, C) of never-scattered light, exactly, in one pass.

    Boundary inflow: the unscattered lattice (``problem.unscattered()``: sigma_s = 0, sigma_a =
    sigma_t) has the diagonal moving block ``-sigma_t I`` (geist2008 eqs. (5)-(7) with sigma_s =
    0), so every direction evolves alone: geist2008 eq. (2) becomes ``f_i(r + c_i) = (1 -
    rho_i(r) sigma_t) f_i(r)`` (rho_i = ``collision.step_density``), a product of per-node factors
    along the upstream line. Its steady state is that product, which ``_transmit`` builds in one
    ordered pass per direction instead of iterating the whole lattice (the same numbers as
    ``solve(problem.unscattered())`` to the solver's tolerance; tested). u = sum_i b_i f_i for
    each boundary condition's inflow b. A beam (``Boundary.beam``): the exactly attenuated beam
    at each node centre, ``beam_fields(problem).direct``.
    """
    nx, ny, nz = problem.shape
    bnd = np.array([b.inflow for b in problem.boundaries], dtype=np.float64)  # (K, 18)
    energy = np.zeros((nx, ny, nz, len(problem.boundaries), problem.channels), dtype)
    for q, t in _transmittances(problem, bnd.any(axis=0), dtype):
        for k in np.nonzero(bnd[:, q])[0]:
            energy[..., k, :] += np.asarray(bnd[k, q], dtype) * t
    if any(b.beam is not None for b in problem.boundaries):
        energy += beam_fields(problem).direct.astype(dtype)
    return energy


def _attenuations(problem: LBProblem, dtype) -> tuple[np.ndarray, np.ndarray]:
    """Per-step survival 1 - rho_q sigma_t (nx, ny, nz, C) of the axial and of the non-axial directions."""
    out = []
    for rho in (problem.density, diagonal_density(problem.density) if problem.lattice == "ordinates" else problem.density):
        att = 1.0 - rho[..., None] * np.array(problem.medium.sigma_t, dtype=np.float64)  # green nodes
        if problem.brown_mask is not None:
            assert problem.brown_medium is not None  # LBProblem.__post_init__ defaults it to brown(medium)
            att[problem.brown_mask] = 1.0 - rho[problem.brown_mask][:, None] * np.array(problem.brown_medium.sigma_t)
        out.append(np.ascontiguousarray(att, dtype=dtype))
    return out[0], out[1]


def _transmittances(problem: LBProblem, wanted: np.ndarray, dtype):
    """Yield (q, t_q) for the wanted directions q: t_q (nx, ny, nz, C) from ``_transmit`` (one buffer, reused)."""
    if not np.any(wanted):
        return
    att = _attenuations(problem, dtype)
    t = np.empty(att[0].shape, dtype)
    for q in range(NQ):
        if wanted[q]:
            _transmit(att[q >= 6], int(_CX[q]), int(_CY[q]), int(_CZ[q]), t)
            yield q, t


def power_weights(lattice: str) -> np.ndarray:
    """(18,) wq_i with power ``sum_i wq_i f_i``: 1 / |c_i| on the ``ordinates`` lattice (a line of
    direction c_i stands for the cross-section dx^2 / |c_i|, ``collision``), 1 on ``geist2008``
    (which conserves the density sum)."""
    if lattice not in LATTICES:
        raise ValueError(f"lattice must be one of {', '.join(LATTICES)}, got {lattice!r}")
    return 1.0 / STEP_LENGTHS[1:] if lattice == "ordinates" else np.ones(NQ)


# --------------------------------------------------------------------------- first-collision source of a beam

#: Largest optical depth per lattice spacing used for a node: rho sigma_t = 1 ("all light interacts") would
#: be infinite; e^-40 ~ 4e-18 is zero in float32 and keeps the march finite.
EXT_MAX = 40.0


@njit(parallel=True, cache=True)
def _march_nodes(ext, dx, dy, dz, out):  # pragma: no cover - compiled
    """out[r] = integral of ext from the centre of node r along (dx, dy, dz) to the grid's edge (index units)."""
    nx, ny, nz = ext.shape
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                out[i, j, k] = _march(ext, i + 0.5, j + 0.5, k + 0.5, dx, dy, dz)


@dataclass(frozen=True, eq=False)
class BeamFields:
    """The exact unscattered beams of a problem and their first-collision sources (``beam_fields``)."""

    direct: np.ndarray
    """(nx, ny, nz, K, C) float64: irradiance of the unscattered beam at each node centre (0 for non-beam rhs)."""
    power: np.ndarray
    """(nx, ny, nz, K, C) float64: power the beam loses in each node's cell, per unit beam irradiance and
    cell volume (lattice spacing 1)."""
    coef: np.ndarray
    """(nmat, C, K, 18) float64: ``(sigma_s / sigma_t) q_i(d) |c_i|``, so the source of direction i is coef x power."""

    def source(self, q: int, mat: np.ndarray) -> np.ndarray:
        """(nx, ny, nz, C, K) post-collision source s_q of moving direction q (= lattice index q + 1)."""
        return self.coef[:, :, :, q][mat] * self.power.transpose(0, 1, 2, 4, 3)


def beam_fields(problem: LBProblem) -> BeamFields:
    """The first-collision source of every beam of ``problem`` (``Boundary.beam``), exactly attenuated.

    A unit beam travelling along d enters the grid from outside. Its optical depth per lattice
    spacing at node r is ``ext = -ln(1 - rho sigma_t)`` (per channel and material; the axial
    per-step survival 1 - rho sigma_t of the lattice exactly, e^-ext; ``EXT_MAX`` caps it), and
    ``depth._march`` integrates it exactly (piecewise constant per cell, Amanatides-Woo) from each
    node centre toward the light, giving tau_c(r). Then, with l_d = 1 / max_k |d_k| the chord of d
    through the centre of a cell and tau_up = tau_c - ext l_d / 2 the depth at the cell's upstream
    face,

        direct(r) = exp(-tau_c)                                  (the beam at the node centre)
        power(r)  = exp(-tau_up) (1 - exp(-ext l_d)) / l_d       (what the cell takes out of it)
        s_i(r)    = (sigma_s / sigma_t) q_i(d) |c_i| power(r)     (``source_weights``; post-collision)

    power is the beam's loss along the chord through the centre times the beam's cross-section
    1 / l_d per unit cell volume (-> ext exp(-tau_c) for thin cells); s_i is its scattered share
    in direction i handed to the lattice line of c_i as power, i.e. divided by that line's
    cross-section 1 / |c_i| (``collision``, "In-scattering"). For d = n_j (a lattice direction)
    and sigma_t = 1, exp(-tau_up) and 1 - exp(-ext l_d) are exactly the lattice's arriving
    unscattered f_j and its rho_j, so the scattered field is exactly that of the Kronecker
    boundary ``base_boundary(j)`` (tested).
    """
    nx, ny, nz = problem.shape
    K, C = len(problem.boundaries), problem.channels
    assert problem.brown_medium is not None  # LBProblem.__post_init__ defaults it to brown(medium)
    media = [problem.medium] + ([problem.brown_medium] if problem.brown_mask is not None and problem.brown_mask.any() else [])
    mat = np.zeros(problem.shape, np.intp)
    if len(media) == 2:
        mat[problem.brown_mask] = 1
    sig_t = np.array([m.sigma_t for m in media])  # (nmat, C)
    direct = np.zeros((nx, ny, nz, K, C))
    power = np.zeros((nx, ny, nz, K, C))
    coef = np.zeros((len(media), C, K, NQ))
    L = STEP_LENGTHS[1:]
    exts = {}
    for c in range(C):
        key = tuple(sig_t[:, c])
        if key not in exts:
            with np.errstate(divide="ignore"):
                e = -np.log(np.clip(1.0 - problem.density * sig_t[mat, c], 0.0, None))
            exts[key] = np.ascontiguousarray(np.minimum(e, EXT_MAX))
    tau = np.empty(problem.shape)
    for k, b in enumerate(problem.boundaries):
        if b.beam is None:
            continue
        d = np.asarray(b.beam)
        chord = 1.0 / float(np.abs(d).max())
        for mi, m in enumerate(media):
            for c in range(C):
                st = m.sigma_t[c]
                if st > 0.0:
                    coef[mi, c, k] = (m.sigma_s[c] / st) * source_weights(d, m.g[c], m.phase, "ordinates") * L
        done = {}
        for c in range(C):
            key = tuple(sig_t[:, c])
            if key not in done:
                ext = exts[key]
                _march_nodes(ext, -d[0], -d[1], -d[2], tau)
                up = np.maximum(tau - 0.5 * chord * ext, 0.0)
                done[key] = (np.exp(-tau), np.exp(-up) * -np.expm1(-chord * ext) / chord)
            direct[..., k, c], power[..., k, c] = done[key]
    return BeamFields(direct, power, coef)


# --------------------------------------------------------------------------- reference update


def _reference_step(f: np.ndarray, problem: LBProblem) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One update of geist2008 eq. (2) in plain numpy (the kernels are tested against it).

    Parameters
    ----------
    f : (nx, ny, nz, 19, K, C) float64 arriving densities (f_0 = 0 after the previous step).

    Returns
    -------
    f_next : (nx, ny, nz, 19, K, C), inflow slots holding the boundary densities
    absorbed : (nx, ny, nz, K, C), the power removed at each node (booked into f_0 and zeroed,
        geist2008 sec. 3), in ``power_weights`` units
    outflow : (K, C), power that left the grid

    The collision is ``f_i + sum_j A_ij rho_j f_j`` (``collision.unit_moving_block`` and
    ``step_density`` of the problem's lattice: on ``geist2008`` this is f + rho Omega f of eqs.
    (5)-(9) with f_0 removed), plus the first-collision source of any beam (``beam_fields``).
    """
    from foliage_tools.lighting.collision import step_density

    rho = problem.density
    assert problem.brown_medium is not None  # LBProblem.__post_init__ defaults it to brown(medium)
    media = [problem.medium, problem.brown_medium]
    A = np.array([unit_moving_block(m, problem.lattice) for m in media])  # (2, C, 18, 18)
    mat = np.zeros(rho.shape, int) if problem.brown_mask is None else problem.brown_mask.astype(int)
    rq = step_density(rho, problem.lattice)  # (nx, ny, nz, 18)
    moving = f[..., 1:, :, :]
    post = np.zeros_like(f)
    post[..., 1:, :, :] = moving + np.einsum("xyzcij,xyzjkc->xyzikc", A[mat], rq[..., :, None, None] * moving)
    if any(b.beam is not None for b in problem.boundaries):
        bf = beam_fields(problem)
        for q in range(NQ):
            post[..., q + 1, :, :] += bf.source(q, mat).transpose(0, 1, 2, 4, 3)
    wq = power_weights(problem.lattice)
    sig_a = np.array([m.sigma_a for m in media])[mat]  # (nx, ny, nz, C)
    absorbed = np.einsum("xyzj,xyzjkc->xyzkc", rq * wq, moving) * sig_a[..., None, :]
    nxt = np.zeros_like(f)
    outflow = np.zeros(f.shape[-2:])
    bnd = np.array([b.inflow for b in problem.boundaries])  # (K, 18)
    for i in range(1, 19):
        c = DIRECTIONS[i]
        dst = tuple(slice(1, None) if v > 0 else slice(None, -1) if v < 0 else slice(None) for v in c)
        src = tuple(slice(None, -1) if v > 0 else slice(1, None) if v < 0 else slice(None) for v in c)
        nxt[..., i, :, :] = bnd[:, i - 1][:, None]  # inflow slots; overwritten where an upstream node exists
        moved = post[src + (i,)]
        nxt[dst + (i,)] = moved
        outflow += wq[i - 1] * (post[..., i, :, :].sum(axis=(0, 1, 2)) - moved.sum(axis=(0, 1, 2)))
    return nxt, absorbed, outflow


# --------------------------------------------------------------------------- outputs


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

