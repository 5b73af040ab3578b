"""``foliage lb``: lattice-Boltzmann light bake per prototype (geist2008 sec. 2.2, 3, 4.2; steele2010 sec. 3.1).

Per prototype: leaf-area density on a cropped grid (``foliage density``'s
area method) -> lattice node density rho = 1 − exp(−G·LAD·Δx) (lighting.collision)
-> steady-state photon energy density u for the requested boundary
conditions (``--bases all``: the 18 Kronecker bases, ambient = their sum),
plus the never-scattered field (``lb.unscattered_energy``, exact, one pass)
that separates direct from scattered light.

Defaults (issue #15, measured in tests/integration/test_lb_layer.py and
tests/unit/test_lb_slab.py): the ``ordinates`` lattice (a diagonal step is
attenuated over its sqrt(2) Δx), the bi-Lambertian phase function of the
leaves on the lattice, and for ``--bases sun`` the sun as a first-collision
source (``lb.sun_source``: the exactly attenuated sun scattered once at every
node; the lattice carries only what is scattered after that), whose first
order of scattering is then replaced by the exact one
(``lighting.single_scatter``: 32 directions marched from every occupied
node; the lattice keeps the higher orders). On the issue's uniform layer at
--resolution 64 that is within −5.4 … +9.7 % of the exact E_scattered in
every depth bin at 30, 60 and 85 degrees (the lattice's own first order:
−1.8 … +26.5 %; the paper's setting ``lattice="geist2008",
sun_source="boundary", phase="hg"``: −22 … +84 %).

Per-leaf conversion (documented in lighting.lb): a randomly oriented two-sided
leaf at a node receives E = u/2; the scattered part is (u − u_unscattered)/2,
sampled trilinearly at the leaf centre. E_direct = |n·s| × u_unscattered(centre):
the leaf's own orientation times the fraction of the sun beam reaching the
node unscattered (u_unscattered = 1 in an empty grid).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path

import numpy as np

from foliage_tools import __version__
from foliage_tools.errors import UsageError
from foliage_tools.geometry.sun import Sun
from foliage_tools.geometry.voxelize import GridSpec, stencil_mask, trilinear_stencil
from scipy import ndimage

from foliage_tools.lighting import lb
from foliage_tools.lighting.lb import single_scatter
from foliage_tools.lighting.lb.collision import LATTICES, PHASES, Medium, brown, density_from_lad, leaf_medium
from foliage_tools.lighting.lb.lattice import UNIT_DIRECTIONS
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.lighting.lb.storage import STORAGES
from foliage_tools.params import BASE_EXTENTS, DEFAULT_RESOLUTION, GRID_PRECISIONS, DensityParams, check_resolution
from foliage_tools.pipeline.density import DensityResult, compute_density, density_for_bake, vdb_path
from foliage_tools.pipeline.plan import available_memory
from foliage_tools.pipeline.direct import DirectChoice, bake_direct
from foliage_tools.pipeline.first_order import march_lb
from foliage_tools.pipeline.gather import bake_gather, check_gather, resolve_rays
from foliage_tools.pipeline.instances import bake_instance_edits, from_prototypes
from foliage_tools.pipeline.world import bake_world
from foliage_tools.pipeline.leafdata import baked_sun_attribute, leaf_primvar_edits, native_instance_warning, vertex_primvar_edits
from foliage_tools.pipeline.report import Progress, Report
from foliage_tools.pipeline.volumes import prototype_volume, volume_path
from foliage_tools.pipeline.stats import LBPrototypeStats, LBStats, sun_stats
from foliage_tools.pipeline.stage import bake_layer, sun_in_prototype
from foliage_tools.scene.model import Prototype, Scene
from foliage_tools.scene.vdb import Grid
from foliage_tools.scene.write import LayerEdits, PrimvarEdit

log = logging.getLogger(__name__)

BASES = ("sun", "all")
#: How the sun enters a ``--bases sun`` bake (lighting.lb): ``first-collision`` (the exactly attenuated sun
#: scattered once at every node, the lattice carrying what is scattered after that) or ``boundary``
#: (geist2008 sec. 3: the sun split over lattice directions as boundary inflow, scattered = u - u_unscattered).
SUN_SOURCES = ("first-collision", "boundary")
#: The first order of scattering of the first-collision sun: exact (lighting.single_scatter) or the lattice's.
SINGLE_SCATTER = ("exact", "lattice")
#: ``--first-order``: the per-leaf first order marched from the exact direct light, or the lattice field's own.
FIRST_ORDERS = ("march", "field")
#: Nodes whose wood fraction exceeds this are "brown" (g = −1, geist2008 sec. 3).
BROWN_WOOD_FRACTION = 0.5


@dataclass(frozen=True)
class LBBakeParams:
    """What ``foliage lb`` bakes."""

    optics: LeafOptics
    sun: tuple[float, float] | None = None
    resolution: int = DEFAULT_RESOLUTION
    """Lattice nodes along the longest edge of the foliage bounds."""
    bases: str = "sun"
    """``sun``: the geist2008 sun boundary for the scene's sun; ``all``: the 18 Kronecker bases + ambient (steele2010 3.1)."""
    tolerance: float = 1e-5
    """Relative residual at which the steady state is accepted."""
    solver: str = "auto"
    """``auto``, ``iterate``, ``bicgstab`` or ``extrapolate`` (lighting.lb)."""
    absorption_scale: float = 1.0
    """σa = scale × (1 − r − t): 1 is the physical leaf; geist2008 used 0.125 (sec. 3)."""
    max_sweeps: int = 20000
    """Sweeps after which the solver stops short of ``tolerance`` (the bake then fails its accuracy check: exit 1)."""
    storage: str = "fp32"
    """``--storage``: the lattice densities stored in ``fp32`` or ``fp16`` (scaled binary16 with float32 arithmetic,
    ``lighting.storage``: half the solver's memory). The grids written are as ``grid_precision`` says either way."""
    grid_precision: str = "float"
    """``--grid-precision``: the LB grids (lbSun, or lbAmbient and lbBase01..18) on disk as ``float`` (float32) or
    ``half`` (binary16 through OpenVDB's saveFloatAsHalf: half the file, each value within 2^-11 relative; read back
    as float32). Only the disk copy: the per-leaf primvars are computed from the float32 fields either way."""
    base_extent: str = "leaves"
    """``--base-extent`` of a ``bases="all"`` bake: its lbAmbient and lbBase01..18 stored at the nodes the
    relighting reads (``leaves``: the trilinear stencils of every leaf's corners and centre, sparse in the
    ``.vdb``, the lattice's shape and origin in each grid's metadata for ``scene.vdb.on_lattice``) or at every
    node (``lattice``). What the relighting reads is the same either way (``BASE_EXTENTS``)."""
    direct: DirectChoice = DirectChoice()
    """``--direct``: what ``primvars:foliage:lb:direct`` holds (exact shadow rays by default, or the lattice's own)."""
    lattice: str = "ordinates"
    """``ordinates`` (true step lengths: a diagonal step attenuates over sqrt2 dx) or the paper's ``geist2008``."""
    sun_source: str = "first-collision"
    """``first-collision`` or ``boundary`` (``SUN_SOURCES``); ``--bases all`` always uses boundary bases."""
    sun_split: str = "geist2008"
    """``sun_source="boundary"``: how the sun is split over lattice directions (``lb.sun_boundary``)."""
    phase: str = "bilambertian"
    """Discrete phase function (``collision.PHASES``): the leaves' ``bilambertian`` or geist2008's ``hg``."""
    single_scatter: str = "exact"
    """With the first-collision sun: ``exact`` replaces the lattice's once-scattered light by the exact one
    (``lighting.single_scatter``, Nakajima & Tanaka 1988's correction: a march over 128 directions from every
    node near the leaves), the lattice keeping the higher orders; ``lattice`` keeps the lattice's own."""
    first_order: str | None = None
    """``--first-order``: the per-leaf E_scattered of a sun bake with the first-collision sun. ``march``: the
    leaves' (and the wood's) exact direct light scattered once and marched through a coarse voxel medium of the
    leaves (lighting.first_order) plus the lattice's later orders at the leaf; ``field``: the lattice field at the
    leaf (its first order per ``single_scatter``). None: ``march`` for such a bake (per leaf 0.132 / 0.202 / 0.192
    on tree_small / the oak / the sapling against the field's 0.257 / 0.280 / 0.290, and within 10 % of the exact
    slab in every depth bin of the uniform layer, README "LB with the marched first order"), ``field`` for a
    relightable bake (``bases="all"``) or a boundary sun, which cannot march. The grids and ``lbIndirect`` are the
    field either way."""
    volume_purpose: str = "default"
    """``--volume-purpose`` of the FoliageLighting volume (``scene.write.VOLUME_PURPOSES``)."""
    gather: int | None = None
    """``--gather N``: rays per leaf of a final gather over the actual leaves (pipeline.gather): the first bounce
    exact, the later ones from LB's E_scattered at the hit leaf. Its result replaces ``:scattered`` and
    ``lbIndirect`` (then per leaf, not interpolated in the lattice); the grids stay the lattice's. 0: off;
    None: ``auto`` (pipeline.gather.auto_rays of the traced leaves with ``bases="sun"``; off with ``"all"``, whose
    lbIndirect is then what the bases relight for the baked sun)."""

    def __post_init__(self) -> None:
        if self.lattice not in LATTICES:
            raise UsageError(f"lattice must be one of {', '.join(LATTICES)}, got {self.lattice!r}.")
        if self.sun_source not in SUN_SOURCES:
            raise UsageError(f"sun source must be one of {', '.join(SUN_SOURCES)}, got {self.sun_source!r}.")
        if self.sun_source == "first-collision" and self.lattice != "ordinates":
            raise UsageError("the first-collision sun source needs the ordinates lattice (use sun_source='boundary' "
                             "with the geist2008 lattice).")
        if self.sun_split not in lb.SUN_SPLITS:
            raise UsageError(f"sun split must be one of {', '.join(lb.SUN_SPLITS)}, got {self.sun_split!r}.")
        if self.phase not in PHASES:
            raise UsageError(f"phase must be one of {', '.join(PHASES)}, got {self.phase!r}.")
        if self.bases not in BASES:
            raise UsageError(f"--bases must be one of {', '.join(BASES)}, got {self.bases!r}.")
        if not (0 < self.tolerance < 1):
            raise UsageError(f"--tolerance must be in (0, 1), got {self.tolerance}.")
        check_resolution(self.resolution)
        if self.solver not in lb.SOLVERS:
            raise UsageError(f"--solver must be one of {', '.join(lb.SOLVERS)}, got {self.solver!r}.")
        if self.storage not in STORAGES:
            raise UsageError(f"--storage must be one of {', '.join(STORAGES)}, got {self.storage!r}.")
        if self.base_extent not in BASE_EXTENTS:
            raise UsageError(f"--base-extent must be one of {', '.join(BASE_EXTENTS)}, got {self.base_extent!r}.")
        if self.grid_precision not in GRID_PRECISIONS:
            raise UsageError(f"--grid-precision must be one of {', '.join(GRID_PRECISIONS)}, got {self.grid_precision!r}.")
        if self.storage == "fp16" and self.solver == "bicgstab":
            raise UsageError("--storage fp16 cannot be combined with --solver bicgstab (its Krylov vectors need more than "
                             "16 bits); use --solver auto, ordered, iterate or extrapolate, or --storage fp32.")
        if not (0 < self.absorption_scale <= 1):
            raise UsageError(f"--absorption-scale must be in (0, 1], got {self.absorption_scale}.")
        if self.max_sweeps < 1:
            raise UsageError(f"--max-sweeps must be at least 1, got {self.max_sweeps}.")
        check_gather(self.gather)
        can_march = self.bases == "sun" and self.sun_source == "first-collision"
        if self.first_order is None:
            object.__setattr__(self, "first_order", "march" if can_march else "field")
        if self.first_order not in FIRST_ORDERS:
            raise UsageError(f"--first-order must be one of {', '.join(FIRST_ORDERS)}, got {self.first_order!r}.")
        if self.first_order == "march" and not can_march:
            raise UsageError("--first-order march needs a sun bake with the first-collision sun (--bases sun, the "
                             "default); a relightable bake (--bases all), whose bases enter as boundary light, takes --first-order field.")
        if self.single_scatter not in SINGLE_SCATTER:
            raise UsageError(f"single scatter must be one of {', '.join(SINGLE_SCATTER)}, got {self.single_scatter!r}.")


def sample_trilinear(field: np.ndarray, grid: GridSpec, points: np.ndarray) -> np.ndarray:
    """Trilinear interpolation of a node field (values at voxel centres) at points; (P, ...) result.

    Points outside the node lattice take the nearest boundary node's value.
    """
    f = np.asarray(field)
    shape = np.asarray(f.shape[:3])
    i0, w = trilinear_stencil(f.shape, grid, points)
    out = 0.0
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                ix = np.minimum(i0[:, 0] + dx, shape[0] - 1)
                iy = np.minimum(i0[:, 1] + dy, shape[1] - 1)
                iz = np.minimum(i0[:, 2] + dz, shape[2] - 1)
                wt = (w[:, 0] if dx else 1 - w[:, 0]) * (w[:, 1] if dy else 1 - w[:, 1]) * (w[:, 2] if dz else 1 - w[:, 2])
                out = out + f[ix, iy, iz] * wt.reshape((-1,) + (1,) * (f.ndim - 3))
    return np.asarray(out)


def base_fields(total: np.ndarray, grid: GridSpec, proto, extent: str) -> tuple[np.ndarray, dict, float]:
    """(nx, ny, nz, K, C) float32 relighting grids to write, their extra grid metadata and the share of the lattice's
    nodes they keep (``LBBakeParams.base_extent``).

    ``leaves``: zero (so inactive, not stored, in the sparse ``.vdb``) away from the nodes the relighting reads: the
    trilinear stencils of every leaf triangle's corners (what ``pipeline.baked_light.load_lb_bases`` samples) and every
    leaf's centre (the per-leaf relighting), with the lattice's shape and origin recorded so a reader can put the
    grid back on it (``scene.vdb.on_lattice``)."""
    fields = total.astype(np.float32)
    if extent == "lattice":
        return fields, {}, 1.0
    points = np.concatenate([proto.triangles(leaves=True).reshape(-1, 3), proto.leaves.centers])
    keep = stencil_mask(total.shape, grid, points)
    fields[~keep] = 0.0
    return fields, {"foliage:latticeShape": tuple(int(n) for n in grid.shape),
                    "foliage:latticeOrigin": tuple(float(v) for v in grid.origin)}, float(keep.mean())


@dataclass(frozen=True)
class LBPrototypeBake:
    index: int
    grid: GridSpec
    total: np.ndarray
    """(nx, ny, nz, K, C) energy density of every boundary condition."""
    unscattered: np.ndarray
    """(nx, ny, nz, K, C) the same without scattering."""
    sun_total: np.ndarray
    """(nx, ny, nz, C) for the scene's sun (relit from the bases for ``all``)."""
    sun_unscattered: np.ndarray
    e_direct: np.ndarray
    """(L, 3) per-leaf E_direct."""
    e_scattered: np.ndarray
    """(L, 3) per-leaf E_scattered."""
    result: lb.LBResult
    seconds: float
    medium: Medium
    """Green-node coefficients the lattice was solved with."""
    density_source: str = "computed"
    """Where the leaf-area density came from: ``computed`` or ``input`` (see ``density_for_bake``)."""
    bases_as_beams: bool = False
    """The 18 bases were solved as beams along the lattice directions (fp16 storage, ``bake_prototype``)."""


def solve_bytes(shape, nrhs: int, *, storage: str, relightable: bool, first_collision: bool, corrected: bool,
                beam_bases: bool) -> float:
    """Bytes ``bake_prototype``'s LB solve holds: what it checks against free memory, and ``foliage plan`` shows.

    The 2 fields of plain iteration in the storage format, the rest in float32: the outputs and temporaries
    (``lb.PLAIN_ITERATION_FIELDS`` - 2, measured for a relightable bake as ``lb.RELIGHTABLE_ITERATION_FIELDS`` - 2);
    a first-collision sun's beam arrays (lb.BeamFields: direct and power in float64, the power again in the run
    layout: ~0.3 field) and its single-scattering correction's float64 energy, extinction, emission and correction
    arrays (~0.6 field); fp16 bases as beams, their source (``lb.BEAM_SOURCE_FIELDS``)."""
    plain = lb.RELIGHTABLE_ITERATION_FIELDS if relightable else lb.PLAIN_ITERATION_FIELDS
    extra = (plain - 2.0 + (0.3 if first_collision else 0.0) + (0.6 if corrected else 0.0)
             + (lb.BEAM_SOURCE_FIELDS if beam_bases else 0.0))
    return lb.memory_bytes(shape, nrhs, 2.0, 2 if storage == "fp16" else 4) + lb.memory_bytes(shape, nrhs, extra)


def _unit_extinction(medium: Medium) -> bool:
    return bool(np.allclose(medium.sigma_t, 1.0, rtol=0.0, atol=1e-12))


def bake_prototype(proto: Prototype, index: int, sun_local: np.ndarray, params: LBBakeParams,
                   dens: DensityResult | None = None) -> LBPrototypeBake:
    if dens is None:
        dens = compute_density(proto, DensityParams(resolution=params.resolution, method="area"))
    grid = dens.grid
    rho = density_from_lad(dens.density, grid.voxel_size)
    medium = leaf_medium(params.optics, absorption_scale=params.absorption_scale, phase=params.phase)
    mask = dens.wood_fraction > BROWN_WOOD_FRACTION
    # steele2010 sec. 3.1: the ambient base B_0 (inflow 1 along every direction) is, by linearity of
    # geist2008 eq. (2), the sum of the 18 Kronecker bases: solve 18 and add them up (5% less work).
    # (A Kronecker base is a beam along a lattice line, which the ordinates lattice attenuates exactly, so
    # its boundary form already is its first-collision form: see lb.beam_fields.)
    first_collision = params.bases == "sun" and params.sun_source == "first-collision"
    # fp16: the 18 bases as beams along the lattice directions, so the rounded lattice holds only their scattered
    # light (as Kronecker inflow it also held the unscattered beam, whose rounding, 2^-11 of the beam, landed on
    # E_scattered = (u - u_unscattered) / 2 at sunlit leaves: up to 2-5 % there). beam_fields: a beam along c_j is
    # exactly base_boundary(j)'s scattered light when sigma_t = 1 on the ordinates lattice (tested), which holds
    # for every leaf and wood medium (collision.leaf_medium: sigma_s = 1 - sigma_a); not on the geist2008 lattice.
    beam_bases = (params.bases == "all" and params.storage == "fp16" and params.lattice == "ordinates"
                  and _unit_extinction(medium) and (not mask.any() or _unit_extinction(brown(medium))))
    boundaries: tuple[lb.Boundary, ...]
    if params.bases == "sun":
        boundaries = (lb.sun_source(sun_local) if first_collision else lb.sun_boundary(sun_local, params.sun_split),)
    elif beam_bases:
        boundaries = tuple(lb.Boundary(b.name, (0.0,) * 18, beam=tuple(UNIT_DIRECTIONS[k]))
                           for k, b in enumerate(lb.relighting_boundaries()[1:], start=1))
    else:
        boundaries = lb.relighting_boundaries()[1:]
    problem = lb.LBProblem(density=rho, medium=medium, boundaries=boundaries,
                           brown_mask=mask if mask.any() else None, brown_medium=brown(medium) if mask.any() else None,
                           lattice=params.lattice)
    correct = first_collision and params.single_scatter == "exact"
    nrhs = len(boundaries) * medium.channels
    need = solve_bytes(grid.shape, nrhs, storage=params.storage, relightable=params.bases == "all",
                       first_collision=first_collision, corrected=correct, beam_bases=beam_bases)
    free = available_memory()
    if need > free:
        raise UsageError(
            f"prototype <{proto.path}>: the LB solve on a {'x'.join(map(str, grid.shape))} grid with "
            f"{len(boundaries) * medium.channels} right-hand sides needs ~{need / 1e9:.1f} GB, {free / 1e9:.1f} GB is available. "
            "Lower --resolution (memory falls with its cube), or use --bases sun (1/18 of --bases all); "
            "`foliage plan` shows the memory before a bake."
        )
    lbp = lb.LBParams(tolerance=params.tolerance, solver=params.solver, max_sweeps=params.max_sweeps, storage=params.storage,
                      beam_outputs=not beam_bases)
    res = lb.solve(problem, lbp)
    total = res.energy_density
    if correct:
        # computed at the occupied nodes; their empty neighbours, which a leaf's trilinear sample also reads,
        # take their neighbours' mean correction
        occupied = rho > 0
        near = ndimage.binary_dilation(occupied, structure=np.ones((3, 3, 3), bool))
        total = single_scatter.corrected_energy(problem, res, mask=occupied, fill=near).astype(np.float32)
    if params.bases == "all":
        total = np.concatenate([total.sum(axis=-2, keepdims=True), total], axis=-2)
        problem = replace(problem, boundaries=lb.relighting_boundaries())
    t_un = time.perf_counter()
    if first_collision:  # the exact beam the solve attenuated for its source
        assert res.beam_direct is not None  # first_collision solves the sun_source beam
        unscattered = res.beam_direct.astype(np.float32)
    else:
        unscattered = lb.unscattered_energy(problem)  # exact one-pass transport, no lattice iteration
    if beam_bases:  # the lattice gave the scattered light alone: the bases' own never-scattered light, exactly
        total += unscattered
    t_un = time.perf_counter() - t_un
    if params.bases == "sun":
        sun_total, sun_un = total[..., 0, :], unscattered[..., 0, :]
    else:
        sun_total = lb.relight(total, sun_local)
        sun_un = lb.relight(unscattered, sun_local)
    scattered_field = lb.scattered_leaf_irradiance(sun_total, sun_un)
    e_scattered = np.maximum(sample_trilinear(scattered_field, grid, proto.leaves.centers), 0.0)
    cos = np.abs(proto.leaves.normals @ sun_local)
    e_direct = cos[:, None] * sample_trilinear(sun_un, grid, proto.leaves.centers)
    return LBPrototypeBake(index, grid, total, unscattered, sun_total, sun_un,
                           e_direct, e_scattered, res, dens.seconds + res.seconds + t_un, medium, dens.source, beam_bases)


def bake_lb(scene: Scene, sun: Sun, params: LBBakeParams, warnings: list[str], progress: Progress) -> list[LBPrototypeBake]:
    baked = scene.leafy_prototypes()
    progress.step(f"lattice-Boltzmann ({params.bases}) for {len(baked)} prototype(s)", total=len(baked))
    out = []
    for i, proto in baked:
        sun_local = sun_in_prototype(scene, i, sun, warnings)
        dens = density_for_bake(scene, proto, DensityParams(resolution=params.resolution, method="area"), warnings)
        bake = bake_prototype(proto, i, sun_local, params, dens)
        if params.bases == "all" and params.storage == "fp16" and not bake.bases_as_beams:
            warnings.append(
                f"prototype <{proto.path}>: with fp16 storage the bases are solved as beams only on the ordinates "
                f"lattice with sigma_t = 1; on the {params.lattice} lattice here they are boundary inflow, whose rounding "
                "puts errors of up to ~5 % on the scattered light of single sunlit leaves (docs/explanation/methods.md, 'LB storage'). "
                "Use fp32 storage where single leaves matter."
            )
        r = bake.result
        log.info("lb <%s>: %s lattice (%s), %s, %d sweeps, residual %.2e%s, %.1f MLUPS, %.2f s", proto.path,
                 "x".join(map(str, bake.grid.shape)), params.bases, r.solver, r.iterations, r.residual,
                 "" if r.converged else " (not converged)", r.mlups, bake.seconds)
        out.append(bake)
        progress.advance()
    return out


def _vertex_indirect(proto: Prototype, bake: LBPrototypeBake) -> list[PrimvarEdit]:
    """primvars:foliage:lbIndirect: scattered irradiance for the scene's sun at every leaf-mesh vertex."""
    field = lb.scattered_leaf_irradiance(bake.sun_total, bake.sun_unscattered)
    edits = []
    for mesh in proto.meshes:
        if mesh.is_leaf and proto.editable:
            values = np.maximum(sample_trilinear(field, bake.grid, mesh.points), 0.0)
            edits.append(PrimvarEdit(prim=mesh.path, name="foliage:lbIndirect", values=values, type="color3f", interpolation="vertex"))
    return edits


def later_orders(bake: LBPrototypeBake, centers: np.ndarray) -> np.ndarray:
    """(L, C) the light an LB sun bake scattered twice or more, at the leaf centres: half the lattice's energy
    density less its unscattered beam and its own first order (``LBResult.once_scattered``; ``lb.irradiance``'s
    factor 1/2), the part ``lighting.single_scatter``'s correction keeps."""
    r = bake.result
    if r.beam_direct is None or r.once_scattered is None:
        raise ValueError("the first-order march on LB needs a first-collision sun bake (--bases sun)")
    later = 0.5 * (np.asarray(r.energy_density, dtype=np.float64) - r.beam_direct - r.once_scattered)[..., 0, :]
    return np.maximum(sample_trilinear(later, bake.grid, centers), 0.0)


def marches(params: LBBakeParams) -> bool:
    """Whether ``params`` take the per-leaf first order from the march (``first_order``): a sun bake with the
    first-collision sun, whose lattice keeps its own first order apart."""
    return params.first_order == "march" and params.bases == "sun" and params.sun_source == "first-collision"


def lb_layer(scene: Scene, sun: Sun, report: Report, progress: Progress, *, out: Path,
             params: LBBakeParams) -> tuple[LayerEdits, LBStats]:
    """``foliage lb``'s computation and layer (``pipeline.stage.bake_layer`` reads before and writes after)."""
    edits = LayerEdits()
    protos: list[LBPrototypeStats] = []
    bakes = bake_lb(scene, sun, params, report.warnings, progress)
    exact = bake_direct(scene, sun, params.direct, progress) if params.direct.mode == "rays" else None
    if marches(params):  # its source is the exact direct light, whatever --direct writes
        later = {b.index: later_orders(b, scene.prototypes[b.index].leaves.centers) for b in bakes}
        bakes = march_lb(scene, sun, params.optics, bakes, later, exact or bake_direct(scene, sun, DirectChoice(), progress),
                         progress)
    gathered = None
    world = exact.world if exact else bake_world(scene)
    # auto gathers a sun bake only: a relightable one's lbIndirect is what its bases give for the baked sun
    rays = 0 if params.gather is None and params.bases == "all" else resolve_rays(params.gather, int(world.offsets[-1]), report.warnings)
    if rays:
        gathered = bake_gather(scene, sun, params.optics, {b.index: b.e_scattered for b in bakes}, rays, progress,
                               world=world)
    for bake in bakes:
        proto = scene.prototypes[bake.index]
        e_direct = exact.per_prototype[bake.index] if exact else bake.e_direct
        e_scattered = gathered.per_prototype[bake.index] if gathered else bake.e_scattered
        g = bake.grid
        meta = {"units": "photon energy density (sun irradiance 1 = 1)", "metersPerUnit": float(scene.meters_per_unit)}
        half = params.grid_precision == "half"  # the LB grids only: the density and earlier grids carried keep theirs
        kept = None
        if params.bases == "sun":
            grids = [Grid("lbSun", bake.sun_total.astype(np.float32), g.origin, g.voxel_size, meta, half=half)]
        else:
            fields, base_meta, kept = base_fields(bake.total, g, proto, params.base_extent)
            grids = [Grid("lbAmbient", fields[..., 0, :], g.origin, g.voxel_size, {**meta, **base_meta}, half=half)]
            grids += [Grid(f"lbBase{k:02d}", fields[..., k, :], g.origin, g.voxel_size, {**meta, **base_meta}, half=half)
                      for k in range(1, 19)]
        r = bake.result
        attrs = {
            "foliage:method": "lb",
            "foliage:voxelSize": float(g.voxel_size),
            "foliage:resolution": tuple(int(n) for n in g.shape),
            "foliage:metersPerUnit": float(scene.meters_per_unit),
            "foliage:iterations": int(r.iterations),
            "foliage:residual": float(r.residual),
            "foliage:seconds": float(bake.seconds),
            "foliage:version": __version__,
            # the medium the grids were solved with (provenance, and what a consumer needs to recompute the
            # never-scattered part of a base with lb.unscattered_energy: rho * sigma_t per node)
            "foliage:lb:sigmaA": tuple(float(v) for v in bake.medium.sigma_a),
            "foliage:lb:sigmaS": tuple(float(v) for v in bake.medium.sigma_s),
            "foliage:lb:g": tuple(float(v) for v in bake.medium.g),
            "foliage:lb:absorptionScale": float(params.absorption_scale),
            "foliage:lb:gridPrecision": params.grid_precision,
            "foliage:tolerance": float(params.tolerance),
            "foliage:lb:storage": params.storage,
            "foliage:lb:roundingLevel": float(r.rounding_level or 0.0),
            **({"foliage:lb:baseExtent": params.base_extent} if params.bases == "all" else {}),
            "foliage:gatherRays": int(rays),
        }
        vol = volume_path(scene, proto)
        edits.volumes.append(prototype_volume(scene, bake.index, vdb_file=vdb_path(out, scene, bake.index), grids=tuple(grids),
                                              attributes=attrs, purpose=params.volume_purpose))
        if not proto.editable:
            report.warnings.append(native_instance_warning(proto, "LB primvars"))
        if gathered:
            edits.primvars += vertex_primvar_edits(proto, "foliage:lbIndirect", e_scattered, type="color3f")
        else:
            edits.primvars += _vertex_indirect(proto, bake)
        edits.primvars += leaf_primvar_edits(proto, "foliage:lb:direct", e_direct, type="color3f")
        edits.primvars += leaf_primvar_edits(proto, "foliage:lb:scattered", e_scattered, type="color3f")
        edits.attributes += baked_sun_attribute(scene, bake.index, "lb", sun.direction)
        if r.rounding_level is not None and not r.residual < params.tolerance:
            report.warnings.append(
                f"prototype <{proto.path}>: LB converged to the fp16 storage's precision at residual {r.residual:.2e}, "
                f"above --tolerance {params.tolerance:g}: a sweep now changes the lattice by no more than its rounding to "
                f"binary16 ({r.rounding_level:.1e}), so more sweeps would only move rounding noise (docs/explanation/methods.md, 'LB storage'). "
                "Use --storage fp32 to reach the tolerance."
            )
        if not r.converged:  # DESIGN.md section 3: a bake that failed its own accuracy check exits 1
            floor = "fp16 storage rarely gets below ~1e-6" if params.storage == "fp16" else "float32 fields rarely get below ~1e-7"
            short = r.iterations < params.max_sweeps  # neither stalled nor out of sweeps: BiCGSTAB's restarts gave up
            why = (f"its residual stopped falling (round-off: {floor})" if r.stalled
                   else f"its solver ({r.solver}) stopped making progress (round-off: {floor})" if short
                   else "it ran out of sweeps (--max-sweeps)")
            fixes = [None if r.stalled or short else "raise --max-sweeps",
                     "loosen --tolerance",
                     None if "bicgstab" in r.solver or params.storage == "fp16" else "try --solver bicgstab"]
            wanted = [x for x in fixes if x]
            report.findings.append(
                f"prototype <{proto.path}>: LB stopped after {int(r.iterations)} sweep(s) ({r.solver}) at residual "
                f"{r.residual:.2e}, above --tolerance {params.tolerance:g}: {why}. The layer was written with that "
                f"residual in its metadata; {', '.join(wanted[:-1]) + ' or ' + wanted[-1] if len(wanted) > 1 else wanted[0]}."
            )
        proto_stats: LBPrototypeStats = {
            "path": proto.path, "volume": vol, "resolution": list(g.shape), "voxel_size": g.voxel_size,
            "solver": r.solver, "iterations": int(r.iterations), "residual": float(r.residual), "converged": bool(r.converged),
            "stalled": bool(r.stalled), "rounding_level": r.rounding_level,
            "mlups": float(r.mlups), "seconds": bake.seconds, "density": bake.density_source, "storage": params.storage,
            "grid_precision": params.grid_precision,
            "e_direct_mean": e_direct.mean(axis=0).tolist(), "e_scattered_mean": e_scattered.mean(axis=0).tolist(),
            "e_scattered_volume_mean": bake.e_scattered.mean(axis=0).tolist(),  # before the gather: march + lattice
            "e_direct_volume_mean": bake.e_direct.mean(axis=0).tolist(),
        }
        if kept is not None:
            proto_stats["base_extent"], proto_stats["base_nodes_kept"] = params.base_extent, kept
        protos.append(proto_stats)
    direct_all = exact.result.e_direct if exact else from_prototypes(world, {b.index: b.e_direct for b in bakes})
    scattered_all = gathered.result.e_scattered if gathered else from_prototypes(world, {b.index: b.e_scattered for b in bakes})
    from foliage_tools.pipeline.forest import forest_light

    # the neighbours' scattered light (a gather traced it already)
    forest = forest_light(scene, sun, params.optics, progress=progress) if gathered is None or world.lone else None
    pv, at = bake_instance_edits(scene, "lb", world, direct_all, scattered_all, forest=forest,
                                 exact_direct=exact)
    if forest is not None:  # steele2010 sec. 3.2's coarse global lattice, where a renderer can read it
        from foliage_tools.pipeline.forest import forest_volume

        edits.volumes.append(forest_volume(scene, forest, out.with_name(f"{out.stem}.forest.vdb"),
                                           params.volume_purpose, "lb"))
    edits.primvars += pv
    edits.attributes += at
    first = protos[0]
    stats: LBStats = {
        "solver": first["solver"], "iterations": first["iterations"], "residual": first["residual"],
        "tolerance": params.tolerance, "converged": all(p["converged"] for p in protos), "resolution": first["resolution"], "bases": params.bases, "mlups": first["mlups"], "storage": params.storage,
        "grid_precision": params.grid_precision, "first_order": "march" if marches(params) else "field",
        "sun": sun_stats(sun),
        "optics": params.optics.as_dict(), "absorption_scale": params.absorption_scale, "prototypes": protos,
        "direct": exact.stats() if exact else {"mode": "volume"},
        "gather": {**gathered.stats(), "on": "lb"} if gathered is not None else {"rays_per_leaf": 0},  # 0: off (auto or asked)
        "forest": forest.stats() if forest is not None else None,
    }
    return edits, stats


def run_lb(path: Path, out: Path, params: LBBakeParams, *, progress: Progress | None = None) -> Report[LBStats]:
    return bake_layer("lb", path, out, params.sun, progress,
                      partial(lb_layer, out=out, params=params))
