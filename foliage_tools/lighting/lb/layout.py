"""The lattice-Boltzmann operator in the kernels' block layout ``(nx, NB, 18, C, G * nz, K)`` (``_Operator``).

It holds a problem's arrays as the kernels read them and applies a sweep, I - T and the dot products for the
solvers. The package docstring (``lighting.lb``, "Layout and kernel") says why the layout is this one.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Literal, overload

import numpy as np

from foliage_tools.lighting.lb.collision import diagonal_density, unit_moving_block
from foliage_tools.lighting.lb.lattice import DIRECTIONS
from foliage_tools.lighting.lb.beam import beam_fields
from foliage_tools.lighting.lb.directions import NQ, power_weights
from foliage_tools.lighting.lb.kernels_collide import SYM_MAX_RUN, _parity_blocks, _symmetry_blocks, sym_row_stride
from foliage_tools.lighting.lb.kernels_field import (
    _balance,
    _dot,
    _field_energy,
    _once_scattered,
    _put_transmitted,
    _rounding_energy,
)
from foliage_tools.lighting.lb.kernels_inplace import _aa_even, _aa_odd
from foliage_tools.lighting.lb.kernels_ordered import _sweep_ordered_rows
from foliage_tools.lighting.lb.kernels_sweep import _sweep_blocks, _sweep_rows
from foliage_tools.lighting.lb.problem import LBProblem
from foliage_tools.lighting.lb.unscattered import _attenuations, _transmittances
from foliage_tools.lighting.lb.storage import HALF_ROUNDING_VARIANCE, from_storage, storage_dtype, to_storage

#: Rows of nz K values at least this long (many right-hand sides) are swept one row at a time (``_sweep_rows``);
#: shorter ones in blocks of ``_BLOCK_VALUES`` // (nz K) rows (``_sweep_blocks``), so that its loops run over
#: about that many values.
_ROW_KERNEL_MIN = 1024
#: About how many values one block's run holds in ``_sweep_blocks`` (G = ``_BLOCK_VALUES`` // (nz K) rows); chosen by
#: timing, docs/lb_notes.md.
_BLOCK_VALUES = 4096


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

    def __init__(self, problem: LBProblem, dtype: str, storage: str = "fp32", beam_outputs: bool = True) -> None:
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
        AE64, AO64 = _parity_blocks(A64)
        self.AE, self.AO = (np.ascontiguousarray(b, dtype=self.dtype) for b in (AE64, AO64))
        self.Q = np.ascontiguousarray(_symmetry_blocks(AE64, AO64), dtype=self.dtype)  # the in-place sweeps' collision
        self.sig_a = np.array([m.sigma_a for m in media], dtype=np.float64)
        self.bnd = np.array([b.inflow for b in problem.boundaries], dtype=np.float64).T  # (18, K)
        self.binf = np.ascontiguousarray(to_storage(self.bnd, self.storage))  # as stored, for the in-place sweeps
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
        self.beams = None
        if self.beam_rhs.any():  # without the beam outputs: in the arithmetic dtype, no direct light
            self.beams = beam_fields(problem) if beam_outputs else beam_fields(problem, self.dtype, with_direct=False)
        if self.beams is None:
            self.pw = np.zeros((nx, self.NB, 1, 1), self.dtype)  # never read (use_src False); indexable per block
            self.cq = np.zeros((1, 1, NQ, 1))
        else:
            assert self.beams.power is not None  # just made
            pw = self._padded(self.beams.power)  # (nx, NB, G, nz, K, C)
            self.pw = np.ascontiguousarray(pw.transpose(0, 1, 5, 2, 3, 4).reshape(nx, self.NB, self.C, self.L), dtype=self.dtype)
            self.cq = np.ascontiguousarray(self.beams.coef.transpose(0, 1, 3, 2))  # (nmat, C, 18, K)
            if not beam_outputs:  # the kernels and the start read the run layout: the array is not needed
                self.beams = replace(self.beams, power=None)
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
        for q, t in _transmittances(problem, self.bnd.any(axis=1), self.dtype):
            _put_transmitted(f, q, t, np.ascontiguousarray(self.bnd[q], dtype=self.dtype), self.G)
        if self.beams is not None:
            att_a, att_d = _attenuations(problem, np.float64)
            _once_scattered(f, att_a, att_d, self.pw, self.cq, self.mat, np.nonzero(self.beam_rhs)[0], self.G)
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
        u = np.empty((self.nx, self.ny, self.nz, self.K, self.C), self.dtype)
        _field_energy(f, self.ny, u)
        return u

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

    @property
    def in_place(self) -> bool:
        """Whether plain iteration runs its unmeasured sweeps as in-place pairs (``sweep_pair``): the block kernel's
        layout (few right-hand sides), and not with fp16 storage, whose plain iteration ends at a fixed point of
        one rounded map (``solvers._at_storage_floor``), which the pairs' different rounding would not share."""
        return not self.long_rows and self.L <= SYM_MAX_RUN and self.storage != np.uint16

    def sweep_pair(self, f: np.ndarray) -> None:
        """f <- two plain sweeps of f, in place (the AA pattern, ``kernels_inplace``): what two ``sweep`` calls give,
        to float rounding, in one field and with no residual. Block layout and fp32 storage only (``in_place``)."""
        assert self.in_place, "sweep_pair needs the block layout (few right-hand sides) and fp32 storage"
        args = (self.rho, self.rhod, self.mat, self.Q, self.pw, self.cE, self.cO, self.use_src, self.binf)
        _aa_even(f, *args)
        _aa_odd(f, *args, sym_row_stride(self.L))

    def rounding(self, f: np.ndarray) -> np.ndarray:
        """(C, K) relative rms error ``sqrt(E[sum e^2] / sum f^2)`` of the rounding to binary16 that the plain sweep
        which wrote the fp16 state f made (``_rounding_energy``): the size of change one more sweep would make by
        rounding alone. fp16 storage only."""
        assert self.storage == np.uint16, "rounding() is for fp16 storage"
        rounded = np.zeros((self.nx, self.C, self.K))
        norm = np.zeros((self.nx, self.C, self.K))
        _rounding_energy(f, self.rho, HALF_ROUNDING_VARIANCE, rounded, norm)
        num, den = rounded.sum(axis=0), norm.sum(axis=0)
        return np.sqrt(np.where(den > 0, _safe_div(num, den), 0.0))

    def ordered_sweep(self, f: np.ndarray, forward: bool) -> None:
        """f <- one in-place ordered sweep (``kernels_ordered``), forward or backward through the nodes."""
        _sweep_ordered_rows(f, self.rho, self.rhod, self.mat, self.A, self.AE, self.AO, forward, self.pw, self.cE, self.cO,
                            self.use_src)

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
