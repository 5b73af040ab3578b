"""Mesh files (OBJ, PLY, glTF/GLB, STL, OFF, ...) -> named triangle parts, through pymeshlab.

pymeshlab reads the file and does the clean-ups it does well (merge close
vertices, remove duplicate and zero-area faces, drop unreferenced vertices,
optional quadric simplification). What it does not keep is what a tree
needs to tell leaves from wood, the names of the file's parts:

* glTF/GLB: pymeshlab loads each mesh as its own layer, labelled with the
  mesh's name: one part per layer.
* OBJ: pymeshlab loads one mesh, so the file is first split here into one
  part per object/group (``o``/``g``) and material (``usemtl``), each
  loaded on its own; the part's name holds all three (matched against the
  leaf pattern). Face indices are made absolute; UVs and normals are not
  carried (no bake reads them).
* Other formats hold one unnamed mesh: one part named after the file.

Readers return plain arrays (trimesh's ``exchange`` habit); nothing here
knows USD.
"""

from __future__ import annotations

import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from foliage_tools.errors import InputError


@dataclass(frozen=True)
class CleanOptions:
    """What pymeshlab does to each part after reading it."""

    merge_distance: float | None = None
    """Vertices closer than this (model units) are merged; None: 1e-6 of the model's bounding-box diagonal (only
    coincident vertices: converted assets often give each triangle its own). Merging at pymeshlab's default 1 % of
    the diagonal would weld neighbouring leaf cards into one leaf."""
    simplify: float | None = None
    """Quadric edge-collapse simplification of the *wood* parts to this fraction of their faces (0 < f < 1); leaves
    are never simplified (a card of 2 triangles has nothing to lose). None: off."""
    clean: bool = True
    """Merge close vertices, remove duplicate and zero-area faces, drop unreferenced vertices."""

    def __post_init__(self) -> None:
        if self.merge_distance is not None and not (self.merge_distance >= 0 and np.isfinite(self.merge_distance)):
            raise ValueError(f"merge_distance must be a finite distance >= 0, got {self.merge_distance}")
        if self.simplify is not None and not (0 < self.simplify < 1):
            raise ValueError(f"simplify must be a fraction of the faces between 0 and 1 (exclusive), got {self.simplify}")


@dataclass(frozen=True)
class Part:
    """One named triangle mesh of a model file."""

    name: str
    """The part's name as the file gives it (object/group and material for OBJ, mesh name for glTF)."""
    material: str
    """The material name (OBJ ``usemtl``), or "" when the file has none."""
    points: np.ndarray
    """(n, 3) float64 vertex positions, model units."""
    triangles: np.ndarray
    """(m, 3) int32 vertex indices."""
    faces_read: int
    """Triangles as read, before the clean-ups."""
    is_leaf: bool = False


def _pymeshlab():
    # pymeshlab bundles an older libtbb.so.12 (interface 12050). Loaded first, it is the TBB numba then finds, and
    # numba's first parallel loop in this process warns "The TBB threading layer requires ... 12060" and falls
    # back (an error under pytest's warnings-as-errors). Starting numba's threads first keeps numba's own TBB,
    # which pymeshlab then shares (same soname); its filters run the same (tests/integration/test_import.py).
    try:
        from numba.np.ufunc import parallel as _numba_parallel

        _numba_parallel._launch_threads()
    except Exception:  # a numba without that private hook: at worst the warning above, in a process that bakes too
        pass
    try:
        import pymeshlab
    except ImportError as exc:  # pragma: no cover - environment problem, reported clearly
        raise InputError("`foliage import` needs pymeshlab: pip install pymeshlab (it is a dependency of foliage-tools; "
                         "reinstall with `pip install -e .`).") from exc
    return pymeshlab


def read_parts(path: Path, *, leaf_pattern: re.Pattern, options: CleanOptions) -> tuple[list[Part], list[str]]:
    """The parts of a model file, cleaned, each classified by ``leaf_pattern`` on its name; and warnings.

    :class:`InputError` (exit 2) names the file when it is missing, of an
    unknown format, unreadable, or holds no faces.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"@{path}@: no such file.")
    pymeshlab = _pymeshlab()
    warnings: list[str] = []
    if path.suffix.lower() == ".obj":
        raw = list(_obj_parts(path, pymeshlab))
    else:
        raw = list(_layers(path, pymeshlab))
    raw = [r for r in raw if len(r[3])]
    if not raw:
        raise InputError(f"@{path}@ holds no faces (a point cloud or an empty file?); there is nothing to bake.")
    lo = np.min([r[2].min(axis=0) for r in raw], axis=0)
    hi = np.max([r[2].max(axis=0) for r in raw], axis=0)
    diagonal = float(np.linalg.norm(hi - lo))
    merge = options.merge_distance if options.merge_distance is not None else 1e-6 * diagonal
    parts = []
    for name, material, points, triangles in raw:
        is_leaf = bool(leaf_pattern.search(name) or (material and leaf_pattern.search(material)))
        simplify = options.simplify if not is_leaf else None
        p, t = _clean(pymeshlab, points, triangles, merge if options.clean else None, options.clean, simplify)
        if not len(t):
            warnings.append(f"@{path}@: part {name!r} has no faces left after the clean-ups (all duplicate or zero-area); "
                            "it is left out.")
            continue
        parts.append(Part(name=name, material=material, points=p, triangles=t, faces_read=len(triangles), is_leaf=is_leaf))
    if not parts:
        raise InputError(f"@{path}@: every face is duplicate or of zero area; there is nothing to bake.")
    return parts, warnings


def _load(pymeshlab, path: Path, ms=None):
    ms = ms if ms is not None else pymeshlab.MeshSet()
    try:
        ms.load_new_mesh(str(path))
    except pymeshlab.PyMeshLabException as exc:
        message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"@{path}@ cannot be read as a mesh ({message}). pymeshlab reads OBJ, PLY, glTF/GLB, STL, OFF, "
                         "3DS, COLLADA and more: is the file complete and of the format its name says?") from None
    return ms


def _arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    return np.array(mesh.vertex_matrix(), dtype=np.float64), np.array(mesh.face_matrix(), dtype=np.int64).reshape(-1, 3)


def _layers(path: Path, pymeshlab):
    """One part per pymeshlab layer (glTF/GLB meshes by name; one unnamed mesh for PLY, STL, ...)."""
    ms = _load(pymeshlab, path)
    n = ms.mesh_number()
    for i in range(n):
        mesh = ms.mesh(i)
        label = mesh.label() if n > 1 else ""
        points, faces = _arrays(mesh)
        yield (label or path.stem), "", points, faces


def _obj_parts(path: Path, pymeshlab):
    """Split an OBJ by object/group and material into temporary OBJs of positions and faces, and load each."""
    vertices: list[str] = []
    groups: dict[tuple[str, str], list[str]] = {}
    obj = group = material = ""
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                head, _, rest = line.strip().partition(" ")
                if head == "v":
                    vertices.append(line if line.endswith("\n") else line + "\n")
                elif head == "o":
                    obj, group = rest.strip(), ""
                elif head == "g":
                    group = rest.strip()
                elif head == "usemtl":
                    material = rest.strip()
                elif head == "f":
                    idx = []
                    for tok in rest.split():
                        v = int(tok.split("/")[0])
                        idx.append(v if v > 0 else len(vertices) + v + 1)  # relative indices count back from here
                    if any(i < 1 or i > len(vertices) for i in idx):
                        raise ValueError(f"face {line.strip()!r} names a vertex that is not defined before it")
                    name = "/".join(n for n in (obj, group) if n) or path.stem
                    groups.setdefault((name, material), []).append("f " + " ".join(map(str, idx)) + "\n")
    except (ValueError, UnicodeError) as exc:
        raise InputError(f"@{path}@ is not a readable OBJ file ({exc}).") from None
    if not vertices and not groups:
        # not an OBJ after all (or empty): let pymeshlab say what it makes of it
        _load(pymeshlab, path)
    with tempfile.TemporaryDirectory(prefix="foliage-import-") as tmp:
        for k, ((name, material), faces) in enumerate(groups.items()):
            part = Path(tmp) / f"part{k}.obj"
            with open(part, "w", encoding="utf-8") as fh:
                fh.writelines(vertices)
                fh.writelines(faces)
            ms = _load(pymeshlab, part)
            ms.meshing_remove_unreferenced_vertices()  # every part was written with all of the file's vertices
            points, tris = _arrays(ms.current_mesh())
            full = f"{name} ({material})" if material and material != name else name
            yield full, material, points, tris


def _clean(pymeshlab, points: np.ndarray, triangles: np.ndarray, merge: float | None, clean: bool,
           simplify: float | None) -> tuple[np.ndarray, np.ndarray]:
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=points, face_matrix=triangles.astype(np.int32)))
    if clean:
        if merge:
            ms.meshing_merge_close_vertices(threshold=pymeshlab.PureValue(merge))
        ms.meshing_remove_duplicate_faces()
        ms.meshing_remove_null_faces()
        ms.meshing_remove_unreferenced_vertices()
    if simplify is not None and ms.current_mesh().face_number() > 4:
        target = max(4, int(round(simplify * ms.current_mesh().face_number())))
        ms.meshing_decimation_quadric_edge_collapse(targetfacenum=target, preservetopology=True, autoclean=True)
    ms.current_mesh().compact()  # face indices into the vertices that are left
    p, t = _arrays(ms.current_mesh())
    return p, t.astype(np.int32)
