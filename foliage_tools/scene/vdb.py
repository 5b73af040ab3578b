"""OpenVDB grids <-> numpy arrays, through Debian's ``pyopenvdb``.

Index space: OpenVDB puts voxel *centres* at integer coordinates, so the
voxel (i, j, k) of a grid whose min corner is ``origin`` has its centre at
``origin + (ijk + 0.5) * voxel_size``. Inactive voxels read back as the
background (0).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import cast

import numpy as np

from foliage_tools.errors import InputError

def _openvdb():
    """Debian's ``pyopenvdb``, imported at first use, so that importing this module (and the pure numerics that
    import the pipeline's modules) does not need it (issue #20)."""
    try:
        import pyopenvdb
    except ImportError as exc:  # pragma: no cover - environment problem, reported clearly
        raise ImportError(
            "pyopenvdb is missing: install Debian's python3-openvdb and make the venv with "
            "--system-site-packages (`make setup` does both)."
        ) from exc
    return pyopenvdb


#: OpenVDB grid class of each grid a bake writes (DESIGN.md section 3, grid names): ``fog volume`` says "a density
#: to render as a participating medium", so only the leaf density carries it; the others are data on the same voxels
#: (fractions, photon energy densities, optical depths, G-factors) that a renderer must not treat as extinction.
#: Any name not listed is ``unknown``. None of them is face-centred, so none is ``staggered``.
FOG_GRIDS = frozenset({"density"})


def grid_class(name: str) -> str:
    """``fog volume`` for the densities, ``unknown`` for every other grid (OpenVDB's ``GridClass`` names)."""
    return "fog volume" if name in FOG_GRIDS else "unknown"


#: The largest finite IEEE binary16 value (what ``Grid.half`` can store); above it OpenVDB writes infinity.
HALF_MAX = 65504.0



def _grid_class_enum(name: str):
    """OpenVDB's ``GridClass`` value of ``grid_class(name)``."""
    gc = _openvdb().GridClass
    return gc.FOG_VOLUME if grid_class(name) == "fog volume" else gc.UNKNOWN


@dataclass(frozen=True)
class Grid:
    """A dense array on an axis-aligned voxel grid, with metadata."""

    name: str
    values: np.ndarray
    """(nx, ny, nz) float32 scalar or (nx, ny, nz, 3) float32 vector values."""
    origin: tuple[float, float, float]
    """World position of the min corner of voxel (0, 0, 0), stage units."""
    voxel_size: float
    metadata: dict = field(default_factory=dict)
    half: bool = False
    """Stored on disk as IEEE binary16 (OpenVDB's ``saveFloatAsHalf``: its own quantisation, which every OpenVDB
    reader expands back to float32); in memory, and read back, the values are float32 either way."""

    @property
    def data_type(self) -> str:
        """USD ``fieldDataType`` token."""
        return "float3" if self.values.ndim == 4 else "float"


def _index_to_world(origin, h: float) -> list[list[float]]:
    # OpenVDB's matrices use the row-vector convention: translation in the last row.
    o = np.asarray(origin, dtype=np.float64) + 0.5 * h
    return [[h, 0, 0, 0], [0, h, 0, 0], [0, 0, h, 0], [float(o[0]), float(o[1]), float(o[2]), 1.0]]


def to_vdb(grid: Grid):
    values = np.ascontiguousarray(grid.values, dtype=np.float32)
    if not np.all(np.isfinite(values)):
        raise ValueError(f"grid {grid.name!r} holds NaN or infinite values; refusing to write it")
    if grid.half and values.size and float(np.abs(values).max()) > HALF_MAX:
        raise ValueError(f"grid {grid.name!r} holds values beyond {HALF_MAX:g}, the largest half float: they would be "
                         "stored as infinite; write it as float")
    if values.ndim == 4:
        g = _openvdb().Vec3SGrid()
        g.copyFromArray(values, ijk=(0, 0, 0), tolerance=(0.0, 0.0, 0.0))
    else:
        g = _openvdb().FloatGrid()
        g.copyFromArray(values, ijk=(0, 0, 0), tolerance=0.0)
    g.transform = _openvdb().createLinearTransform(_index_to_world(grid.origin, grid.voxel_size))
    g.name = grid.name
    g.gridClass = _grid_class_enum(grid.name)
    for key, value in grid.metadata.items():
        g[key] = value
    if grid.half:  # only then: even False adds is_saved_as_half_float to the metadata, and float files stay as they were
        g.saveFloatAsHalf = True
    return g


def write_vdb(path: Path, grids: list[Grid], *, metadata: dict | None = None, carried: Sequence[tuple[Path, str]] = ()) -> None:
    """Write grids to ``path`` (not atomic by itself: pass a temporary path).

    ``carried``: (file, grid name) of grids an earlier stage wrote, copied as they
    are (sparse tree, transform, metadata) into this file after ``grids``, so one
    file holds every field of a volume (DCCs such as Blender read one file per
    volume). Their grid class is set by name like the new grids'. They keep the
    precision their stage wrote them in (OpenVDB reads ``saveFloatAsHalf`` back
    with the grid): the stage that made a grid decides how it is stored.
    """
    written = [to_vdb(g) for g in grids]
    for source, name in carried:
        written.append(_read_raw(Path(source), name))
    names = [g.name for g in written]
    if len(set(names)) != len(names):
        raise ValueError(f"grid names must be unique within a file, got {names}")
    _openvdb().write(str(path), grids=written, metadata=dict(metadata or {}))


def unreadable_grids(path: Path) -> str | None:
    """Why a ``.vdb`` just written does not read back whole (None: every grid reads), one grid in memory at a time.

    A file cut short (a file-size limit, a full disk that the writer did not report) still lists its grids; reading
    each one finds the cut."""
    try:
        names = [g.name for g in _openvdb().readAllGridMetadata(str(path))]
        for name in names:
            _openvdb().read(str(path), name)
    except Exception as exc:  # pyopenvdb raises assorted types for corrupt files
        return f"not a whole OpenVDB file: {exc}"
    return None


def _read_raw(path: Path, name: str):
    """One grid of a file as pyopenvdb holds it, with its class set by name; :class:`InputError` if unreadable."""
    if name not in grid_names(path):
        raise InputError(f"@{path}@ has no grid named {name!r}.")
    try:
        g = _openvdb().read(str(path), name)
    except Exception as exc:  # pyopenvdb raises assorted types for corrupt files
        raise InputError(f"@{path}@: grid {name!r} cannot be read ({exc}).") from None
    g.gridClass = _grid_class_enum(name)
    return g


def _why(exc: BaseException) -> str:
    """What OpenVDB said about a file it could not read, in at most a line: a cut or garbled file can make it quote
    hundreds of megabytes of what it took for a name."""
    text = " ".join(str(exc).split())
    return text if len(text) <= 160 else text[:157] + "..."


def unreadable(path: Path) -> str | None:
    """Why ``path`` cannot be read as an OpenVDB file before anything opens it (missing, a directory, a FIFO or a
    device, which would block the read: ``dependencies.file_problem``), as ``@path@ <why>.``; None for a regular file."""
    from foliage_tools.scene.dependencies import file_problem

    problem = file_problem(path)
    return None if problem is None else f"@{path}@ {problem}; an OpenVDB file is a regular file."


def _descriptors(path: Path) -> list[tuple[str, str, str]]:
    """(name, value type, class) of every grid of a ``.vdb``, read once per file version; :class:`InputError` naming
    ``path`` as given if it is not a regular file OpenVDB can read."""
    path = Path(path)
    problem = unreadable(path)
    if problem is not None:
        raise InputError(problem)
    st = path.stat()
    try:
        return _read_descriptors(str(path.resolve()), st.st_size, st.st_mtime_ns, st.st_ino)
    except Exception as exc:  # pyopenvdb raises assorted types for corrupt files
        raise InputError(f"@{path}@: not a readable OpenVDB file ({_why(exc)}).") from None


@lru_cache(maxsize=64)
def _read_descriptors(path: str, _size: int, _mtime: int, _ino: int) -> list[tuple[str, str, str]]:
    return [(g.name, str(g.valueTypeName), str(g.gridClass)) for g in _openvdb().readAllGridMetadata(path)]


def grid_classes(path: Path) -> dict[str, str]:
    """{grid name: OpenVDB grid class name} of a ``.vdb`` (``fog volume``, ``unknown``, ...)."""
    return {name: klass for name, _, klass in _descriptors(path)}


def file_metadata(path: Path) -> dict:
    """The file-level metadata of a ``.vdb`` (``write_vdb``'s ``metadata``); empty if it cannot be read."""
    if unreadable(Path(path)) is not None:
        return {}  # never opened: a FIFO would block the read
    try:
        return dict(_openvdb().readMetadata(str(path)))
    except Exception:  # pyopenvdb raises assorted types for corrupt files; the grid readers report those
        return {}


def grid_names(path: Path) -> list[str]:
    """Names of the grids in a ``.vdb`` file; :class:`InputError` if it is missing, not a regular file or unreadable."""
    return [name for name, _, _ in _descriptors(Path(path))]


#: The most voxels :func:`read_grid` makes dense (2 GiB of float32): more than any bake writes (the density's limit),
#: so a grid spanning more is a garbled file, not one to allocate for.
MAX_DENSE_VOXELS = 1024**3 // 2

#: The value types of the grids the bakes write and read (FloatGrid, Vec3SGrid).
READ_TYPES = ("float", "vec3s")


def place_on_lattice(grid: Grid, shape, origin) -> Grid:
    """``grid`` put on the lattice of ``shape`` nodes whose voxel (0, 0, 0) starts at ``origin`` (same voxel size),
    zero where the grid holds nothing; ValueError if the grid reaches outside it."""
    shape = tuple(int(n) for n in shape)
    offset = np.rint((np.asarray(grid.origin) - np.asarray(origin, dtype=np.float64)) / grid.voxel_size).astype(np.int64)
    n = np.asarray(grid.values.shape[:3], dtype=np.int64)
    if np.any(offset < 0) or np.any(offset + n > np.asarray(shape)):
        raise ValueError(f"grid {grid.name!r} reaches outside the lattice its metadata records ({shape} at {tuple(origin)})")
    values = np.zeros(shape + grid.values.shape[3:], dtype=np.float32)
    values[tuple(slice(int(a), int(a + b)) for a, b in zip(offset, n))] = grid.values
    return replace(grid, values=values, origin=(float(origin[0]), float(origin[1]), float(origin[2])))


def on_lattice(grid: Grid) -> Grid:
    """``grid`` placed back on the lattice it was baked on (``place_on_lattice``) when its metadata records one
    (``foliage:latticeShape`` / ``foliage:latticeOrigin``: ``foliage lb --base-extent leaves``); else unchanged.

    :func:`read_grid` returns a grid over its active voxels, which for a sparse grid is smaller than its lattice.
    """
    shape, origin = grid.metadata.get("foliage:latticeShape"), grid.metadata.get("foliage:latticeOrigin")
    if shape is None or origin is None:
        return grid
    return place_on_lattice(grid, shape, origin)


def read_grid(path: Path, name: str) -> Grid:
    """Read one grid as a dense array over its active bounding box; :class:`InputError` if the file is not a regular
    file OpenVDB can read, has no such grid, holds it as another type than float or vec3s, or it holds NaN or Inf."""
    path = Path(path)
    types = {n: t for n, t, _ in _descriptors(path)}
    if name not in types:
        raise InputError(f"@{path}@ has no grid named {name!r}.")
    if types[name] not in READ_TYPES:
        raise InputError(f"@{path}@: grid {name!r} holds {types[name]} values; foliage grids hold float or vec3s. Re-run "
                         "the bake that wrote it, or point the field at the grid it means.")
    try:
        g = _openvdb().read(str(path), name)
    except Exception as exc:
        raise InputError(f"@{path}@: grid {name!r} cannot be read ({_why(exc)}).") from None
    lo, hi = g.evalActiveVoxelBoundingBox()
    if g.activeVoxelCount() == 0:
        lo, hi = (0, 0, 0), (0, 0, 0)
    shape = tuple(int(b - a + 1) for a, b in zip(lo, hi))
    if math.prod(shape) > MAX_DENSE_VOXELS:
        raise InputError(f"@{path}@: grid {name!r} spans {'x'.join(map(str, shape))} voxels, more than the "
                         f"{MAX_DENSE_VOXELS:,} a bake reads (its stage writes at most a 512-voxel edge); re-run the bake "
                         "that wrote it.")
    if isinstance(g, _openvdb().Vec3SGrid):
        arr = np.zeros(shape + (3,), dtype=np.float32)
    else:
        arr = np.zeros(shape, dtype=np.float32)
    g.copyToArray(arr, ijk=lo)
    bad = int(np.count_nonzero(~np.isfinite(arr)))
    if bad:
        # a stage reading it would carry the NaN into every leaf (or crash in a solver); name the file instead
        raise InputError(f"@{path}@: grid {name!r} holds {bad} NaN or infinite voxel(s); re-run the bake that wrote it "
                         "(or delete it and the layer that names it).")
    w0 = np.array(g.transform.indexToWorld(lo))
    w1 = np.array(g.transform.indexToWorld((lo[0] + 1, lo[1], lo[2])))
    h = float(np.linalg.norm(w1 - w0))
    origin = cast("tuple[float, float, float]", tuple(float(x) for x in (w0 - 0.5 * h)))  # w0 is a 3-vector
    meta = {k: v for k, v in g.metadata.items() if not k.startswith("file_")}
    half = bool(meta.pop("is_saved_as_half_float", False))  # OpenVDB's own key for saveFloatAsHalf: Grid.half
    return Grid(name=name, values=arr, origin=origin, voxel_size=h, metadata=meta, half=half)
