"""What the lattice-Boltzmann solver is given and gives back: ``LBProblem``, ``LBParams``, ``LBResult`` and its errors.

The package docstring (``lighting.lb``, "Stability policy: reject") says why ``LBProblem`` refuses
rho * sigma_t > 1 rather than clamping it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from foliage_tools.errors import UsageError
from foliage_tools.lighting.lb.collision import LATTICES, Medium, brown, diagonal_density
from foliage_tools.lighting.lb.boundaries import Boundary
from foliage_tools.lighting.lb.storage import STORAGES

SOLVERS = ("auto", "iterate", "bicgstab", "extrapolate", "ordered")


class LatticeStabilityError(UsageError, ValueError):
    """rho * sigma_t > 1 somewhere: the explicit lattice update would be unstable."""


class LBNumericalError(ArithmeticError):
    """The solver produced non-finite values (raised instead of returning them).

    Not a :class:`~foliage_tools.errors.FoliageError`: it is no fault of the input, so the command line treats it as
    any internal failure (exit 3, with a crash log holding the traceback)."""


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
    Lyusternik extrapolation, no extra memory), ``auto`` (iterate; when slow, BiCGSTAB if its 6
    fields fit in ``memory_limit``, else extrapolation) or ``ordered`` (in-place sweeps in alternating
    lexicographic order, ``kernels_ordered``: converge per order of scattering rather than per node
    the light crosses; each counts as one sweep, and a plain measuring sweep decides convergence)."""
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
    beam_outputs: bool = True
    """With beam right-hand sides: add the beams' exact unscattered light to ``energy_density`` and return it, their
    power and the once-scattered field (``LBResult.beam_direct``, ``beam_power``, ``once_scattered``). False: the
    energy density is the lattice's scattered light alone, and the beam arrays are in the arithmetic dtype and dropped
    as soon as the solve has its source (a relightable bake's 18 bases as beams: ~0.9 field less)."""

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
    """The residual is below the tolerance, or (fp16 storage) at the storage's rounding level: ``rounding_level``."""
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
    stalled: bool = False
    """The solve stopped because its residual stopped falling (round-off: float32's ~1e-8, fp16 storage's ~1e-6;
    ``solvers.STALL_SWEEPS``), not at the tolerance or at ``max_sweeps``."""
    rounding_level: float | None = None
    """fp16 storage: the relative rms change one sweep's rounding to binary16 makes, when the solve stopped because
    its own change per sweep was no larger and no longer fell: converged to the storage's precision, whether its
    residual is above the tolerance or not (``solvers._at_storage_floor``). None when it stopped otherwise."""
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
