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
values unchanged. The residual is that of the stored (rounded) values, so
plain fp16 sweeps end at a fixed point of the rounded map, whose distance from
the exact steady state is bounded by 2^-11 (I - T)^-1 |f| componentwise
(tests/unit/test_lb_storage.py). Ordered sweeps (``auto``, ``ordered``) stop
earlier, converged, once the residual no longer falls and no right-hand side
changes by more than the sweep rounded it (``solvers._at_storage_floor``: the
error bound is then at most twice the fixed point's). BiCGSTAB is not offered
with fp16.

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

* In place (``kernels_inplace``, ``_Operator.sweep_pair``): plain
  iteration's unmeasured sweeps, with short rows and fp32 storage, run in
  pairs on one field (the AA pattern: the even step writes each node's
  post-collision values back into its own opposite slots, the odd step
  gathers along the links and scatters back to where it read), so a pair
  moves each value once each way with no read-for-ownership of a second
  field. They collide by symmetry blocks (``_collide_sym``): the moving block
  commutes with the cube's 48 symmetries, so in symmetry-adapted coordinates
  of the pair sums and differences (``_symmetry_bases``) its parity halves
  are 2 x 2 blocks and scalars, 30 multiply-adds where the products take 162,
  and the post-collision values are clamped at 0 (the exact ones are >= 0;
  the transforms leave round-off of either sign). fp16 keeps the push sweeps,
  whose one rounded map its stopping rule relies on.

Ordered sweeps (``kernels_ordered``) work a z-row at a time: within a row only
the z-step along the visiting order links nodes, so the rest collides
vectorized over the row and that step goes node by node.

``_reference_step`` is the plain numpy version of the update on the paper's 19
directions that the push kernels are tested against; the in-place pair is
tested against two push sweeps, the ordered rows against a node-by-node sweep.

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
that follow them are fused into the sweep. ``solver="ordered"`` sweeps in
place, visiting the nodes in lexicographic order and its reverse in turn
(Gauss-Seidel; ``kernels_ordered``): a value pushed forward is read again in
the same sweep, so half the directions cross the whole grid per sweep and the
residual falls per order of scattering, not per node crossed, and each
ordered sweep from the second on is followed by a plain measuring one.
``"auto"`` (the default) runs ordered sweeps first, up to
``solvers.AUTO_ORDERED_SWEEPS`` (24); what they leave, it iterates, estimates the
per-sweep contraction rate q from the residual history, and switches to BiCGSTAB (warm-started from the
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

Modules
-------
One per concept; this package re-exports what callers use. The medium:
``lattice`` (the D3Q19 directions, weights and step lengths), ``collision``
(the scattering kernel Omega, geist2008 eqs. (5)-(9), and the medium from the
leaves' optics), ``storage`` (fp32/fp16 field storage for the numba kernels)
and ``single_scatter`` (the exact once-scattered light and the lattice's
correction to it). The solver: ``boundaries`` (the right-hand sides), ``problem`` (``LBProblem``, ``LBParams``,
``LBResult``, the errors), ``directions`` (the 18 stored directions,
``power_weights``), the numba kernels ``kernels_collide`` (parity-split
collision), ``kernels_stream`` (streaming pieces), ``kernels_sweep`` (the fused
sweeps) and ``kernels_field`` (balance, once-scattered start, vector updates),
``layout`` (``_Operator``), ``solvers`` (``solve``, ``memory_bytes``),
``unscattered`` (``unscattered_energy``), ``beam`` (``beam_fields``), ``oracle``
(``_reference_step``) and ``irradiance`` (leaf irradiance, ``relight``); ``kernels_ordered`` is the in-place
ordered sweep.
"""

from __future__ import annotations

from foliage_tools.lighting.lb.beam import EXT_MAX as EXT_MAX
from foliage_tools.lighting.lb.beam import BeamFields, beam_fields
from foliage_tools.lighting.lb.boundaries import (
    SUN_SPLITS,
    Boundary,
    ambient_boundary,
    base_boundary,
    relighting_boundaries,
    sun_boundary,
    sun_source,
)
from foliage_tools.lighting.lb.directions import NAXIAL_PAIRS as NAXIAL_PAIRS
from foliage_tools.lighting.lb.directions import NH as NH
from foliage_tools.lighting.lb.directions import NQ as NQ
from foliage_tools.lighting.lb.directions import power_weights
from foliage_tools.lighting.lb.irradiance import leaf_irradiance, relight, scattered_leaf_irradiance
from foliage_tools.lighting.lb.kernels_collide import _parity_blocks as _parity_blocks
from foliage_tools.lighting.lb.kernels_sweep import _LONG_RUN_MIN as _LONG_RUN_MIN
from foliage_tools.lighting.lb.layout import _BLOCK_VALUES as _BLOCK_VALUES
from foliage_tools.lighting.lb.layout import _ROW_KERNEL_MIN as _ROW_KERNEL_MIN
from foliage_tools.lighting.lb.layout import _Operator as _Operator
from foliage_tools.lighting.lb.oracle import _reference_step as _reference_step
from foliage_tools.lighting.lb.problem import SOLVERS as SOLVERS
from foliage_tools.lighting.lb.problem import LatticeStabilityError, LBNumericalError, LBParams, LBProblem, LBResult
from foliage_tools.lighting.lb.solvers import BEAM_SOURCE_FIELDS as BEAM_SOURCE_FIELDS
from foliage_tools.lighting.lb.solvers import PLAIN_ITERATION_FIELDS as PLAIN_ITERATION_FIELDS
from foliage_tools.lighting.lb.solvers import RELIGHTABLE_ITERATION_FIELDS as RELIGHTABLE_ITERATION_FIELDS
from foliage_tools.lighting.lb.solvers import memory_bytes, solve
from foliage_tools.lighting.lb.unscattered import unscattered_energy

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
