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
from typing import Any

import numpy as np

from foliage_tools.scene.dependencies import require_file
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


def read_parts(path: Path, *, leaf_pattern: Any, options: CleanOptions) -> tuple[list[Part], list[str]]:
    """The parts of a model file, cleaned, each classified by ``leaf_pattern`` (a compiled pattern: its ``search``)
    on its name; and warnings.

    :class:`InputError` (exit 2) names the file when it is missing, of an
    unknown format, unreadable, or holds no faces.
    """
    path = Path(path)
    require_file(path, "Give the mesh file to import.")  # a FIFO or a device is named as such, never opened
    check_file(path)
    pymeshlab = _pymeshlab()
    warnings: list[str] = []
    if path.suffix.lower() == ".obj":
        raw = list(_obj_parts(path, pymeshlab))
    else:
        raw = list(_layers(path, pymeshlab))
    raw = [r for r in raw if len(r[3])]
    for name, _material, points, triangles in raw:
        check_arrays(path, name, points, triangles)
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


def check_arrays(path: Path, part: str, points: np.ndarray, triangles: np.ndarray) -> None:
    """A part's arrays as a mesh needs them: finite coordinates, every index one of its points. pymeshlab trusts
    them (an index past the points corrupts its memory), so :class:`InputError` names the file and the part first."""
    if points.ndim != 2 or points.shape[1] != 3 or triangles.ndim != 2 or triangles.shape[1] != 3:
        raise InputError(f"@{path}@: part {part!r} is not a triangle mesh of 3-D points as read "
                         f"(points {points.shape}, faces {triangles.shape}).")
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise InputError(f"@{path}@: part {part!r}: vertex {int(np.argmax(bad))} (and {int(bad.sum()) - 1} more) has a "
                         "NaN or infinite coordinate; fix or remove those vertices in the file.")
    if len(triangles):
        wrong = (triangles < 0) | (triangles >= len(points))
        if wrong.any():
            face = int(np.argmax(wrong.any(axis=1)))
            raise InputError(f"@{path}@: part {part!r}: face {face} names vertex {int(triangles[face][wrong[face]][0])}, "
                             f"but the part has {len(points)} vertices (0 to {len(points) - 1}); the file is damaged.")


def check_file(path: Path) -> None:
    """Check what pymeshlab's readers trust before they read it (they crash, or ask for gigabytes, on a count or
    an index the file does not back): PLY headers' element counts, OFF counts, indices and coordinates, glTF
    accessors, buffer views and indices. :class:`InputError` names the file and the element."""
    suffix = path.suffix.lower()
    if suffix == ".ply":
        _check_ply(path)
    elif suffix == ".off":
        _check_off(path)
    elif suffix in (".gltf", ".glb"):
        _check_gltf(path)


#: Bytes of a PLY scalar type, by its names.
_PLY_SIZES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2, "ushort": 2, "uint16": 2,
              "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def _check_ply(path: Path) -> None:
    """Each ``element NAME COUNT`` of the header: a whole number >= 0 that the rest of the file has room for."""
    with open(path, "rb") as fh:
        head = fh.read(1 << 16)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return  # not a PLY header pymeshlab could read either: its own message says so
    body = path.stat().st_size - (head.index(b"\n", end) + 1 if b"\n" in head[end:] else end + 10)
    ascii_ = b"format ascii" in head[:end]
    elements: list[list] = []  # [name, count, least bytes of a row]
    for raw in head[:end].decode("ascii", "replace").splitlines():
        words = raw.split()
        if len(words) >= 3 and words[0] == "element":
            if not re.fullmatch(r"\d+", words[2]):
                raise InputError(f"@{path}@: the PLY header says `element {words[1]} {words[2]}`; an element count is "
                                 "a whole number >= 0. The file is damaged or was not written as PLY.")
            elements.append([words[1], int(words[2]), 0])
        elif len(words) >= 3 and words[0] == "property" and elements:
            kind = words[2] if words[1] == "list" else words[1]  # a list's least: its count, no items
            elements[-1][2] += 2 if ascii_ else _PLY_SIZES.get(kind, 1)
    room = 0
    for name, count, row in elements:
        room += count * max(row, 2 if ascii_ else 1)
        if room > body:
            raise InputError(f"@{path}@: the PLY header says `element {name} {count}`, but the {body:,} bytes after "
                             f"the header cannot hold that many; the header does not match the data (a damaged or "
                             "cut file).")


def _check_off(path: Path) -> None:
    """An OFF's counts (whole numbers >= 0, backed by the lines that follow), its coordinates (finite) and its face
    indices (each one of its vertices)."""
    with open(path, "rb") as fh:
        text = fh.read().decode("utf-8", "replace")
    lines = [ln.split("#", 1)[0].split() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln]
    if not lines or not lines[0][0].upper().endswith("OFF") or len(lines[0][0]) > 5 or "BINARY" in lines[0]:
        return  # binary or n-dimensional OFF, or not OFF: pymeshlab's reader says what it makes of it
    counts, rest = (lines[0][1:], lines[1:]) if len(lines[0]) > 1 else ((lines[1] if len(lines) > 1 else []), lines[2:])
    if len(counts) < 2 or not all(re.fullmatch(r"\d+", c) for c in counts[:3]):
        raise InputError(f"@{path}@: the OFF counts line is {' '.join(counts)!r}; it must give the vertices, faces "
                         "(and edges) as whole numbers >= 0.")
    nv, nf = int(counts[0]), int(counts[1])
    if nv + nf > len(rest):
        raise InputError(f"@{path}@: the OFF header gives {nv:,} vertices and {nf:,} faces, but {len(rest):,} lines "
                         "follow; the header does not match the data (a damaged or cut file).")
    for i, words in enumerate(rest[:nv]):
        try:
            xyz = [float(w) for w in words[:3]]
        except ValueError:
            xyz = []
        if len(xyz) != 3 or not all(np.isfinite(xyz)):
            raise InputError(f"@{path}@: OFF vertex {i} is {' '.join(words)!r}; a vertex is 3 finite coordinates.")
    for j, words in enumerate(rest[nv:nv + nf]):
        try:
            k = int(words[0])
            idx = [int(w) for w in words[1:1 + k]]
        except ValueError:
            k, idx = -1, []
        if k < 1 or len(idx) != k:
            raise InputError(f"@{path}@: OFF face {j} is {' '.join(words)!r}; a face is its vertex count, then "
                             "that many vertex indices.")
        wrong = [v for v in idx if not 0 <= v < nv]
        if wrong:
            raise InputError(f"@{path}@: OFF face {j} names vertex {wrong[0]}, but the file has {nv:,} vertices "
                             f"(0 to {nv - 1}); the file is damaged.")


#: glTF accessors: bytes of a component type, components of an element type.
_GLTF_COMPONENT = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_GLTF_DTYPE = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_GLTF_TYPE = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def _gltf_document(path: Path) -> tuple[dict, bytes | None]:
    """A glTF's JSON and, for a GLB, its binary chunk."""
    import json

    data = path.read_bytes()
    try:
        if data[:4] == b"glTF":
            if len(data) < 20:
                raise ValueError("the GLB header is cut")
            size = int.from_bytes(data[12:16], "little")
            doc = json.loads(data[20:20 + size])
            rest = data[20 + size:]
            binary = rest[8:8 + int.from_bytes(rest[:4], "little")] if len(rest) >= 8 else None
        else:
            doc, binary = json.loads(data), None
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"@{path}@ is not a readable glTF file ({exc}).") from None
    if not isinstance(doc, dict):
        raise InputError(f"@{path}@ is not a readable glTF file (its JSON is not an object).")
    return doc, binary


def _gltf_buffer(path: Path, doc: dict, i: int, binary: bytes | None) -> bytes | None:
    """The bytes of buffer ``i``: GLB's chunk, a data: URI or a file beside ``path``; None when it cannot be had
    here (pymeshlab then says so)."""
    import base64
    import binascii
    from urllib.parse import unquote

    uri = doc["buffers"][i].get("uri")
    if uri is None:
        return binary
    if not isinstance(uri, str):
        return None
    if uri.startswith("data:"):
        try:
            return base64.b64decode(uri.partition(",")[2], validate=False)
        except (binascii.Error, ValueError):
            return None
    try:
        return (path.parent / unquote(uri)).read_bytes()
    except OSError:
        return None


def _check_gltf(path: Path) -> None:
    """Every accessor a mesh reads: a count >= 1 that its buffer view holds, in a view its buffer holds; every
    index one of its primitive's positions; positions finite."""
    doc, binary = _gltf_document(path)

    def items(key: str) -> list:
        value = doc.get(key, [])
        return value if isinstance(value, list) else []

    buffers, views, accessors = items("buffers"), items("bufferViews"), items("accessors")
    data: dict[int, bytes | None] = {}

    def damaged(what: str) -> InputError:
        return InputError(f"@{path}@: {what}; the file is damaged (its counts do not match its data).")

    def read(a: int) -> np.ndarray | None:
        """Accessor ``a``'s elements (checked against its view and buffer), or None if its data is not here."""
        if not isinstance(a, int) or not 0 <= a < len(accessors) or not isinstance(accessors[a], dict):
            raise damaged(f"a mesh names glTF accessor {a!r}, which the file does not have ({len(accessors)} accessors)")
        acc = accessors[a]
        count, ctype, etype = acc.get("count"), acc.get("componentType"), acc.get("type")
        if not isinstance(count, int) or isinstance(count, bool) or count < 1:
            raise damaged(f"glTF accessor {a} has count {count!r}, and a count is a whole number >= 1")
        if ctype not in _GLTF_COMPONENT or etype not in _GLTF_TYPE:
            raise damaged(f"glTF accessor {a} has componentType {ctype!r} and type {etype!r}, which glTF does not define")
        if "sparse" in acc or "bufferView" not in acc:
            return None  # zeros or sparse values: pymeshlab's reader has them
        v = acc["bufferView"]
        if not isinstance(v, int) or not 0 <= v < len(views) or not isinstance(views[v], dict):
            raise damaged(f"glTF accessor {a} names bufferView {v!r}, which the file does not have")
        view = views[v]
        b, length, start = view.get("buffer"), view.get("byteLength"), view.get("byteOffset", 0)
        if not isinstance(b, int) or not 0 <= b < len(buffers) or not isinstance(buffers[b], dict):
            raise damaged(f"glTF bufferView {v} names buffer {b!r}, which the file does not have")
        if not all(isinstance(x, int) and x >= 0 for x in (length, start)):
            raise damaged(f"glTF bufferView {v} has byteOffset {start!r} and byteLength {length!r}")
        if b not in data:
            data[b] = _gltf_buffer(path, doc, b, binary)
        blob = data[b]
        if blob is None:
            return None
        if start + length > len(blob):
            raise damaged(f"glTF bufferView {v} takes bytes {start:,} to {start + length:,} of buffer {b}, which "
                          f"holds {len(blob):,}")
        size = _GLTF_COMPONENT[ctype] * _GLTF_TYPE[etype]
        stride = view.get("byteStride") or size
        offset = acc.get("byteOffset", 0)
        if not (isinstance(stride, int) and stride >= size and isinstance(offset, int) and offset >= 0):
            raise damaged(f"glTF accessor {a} has byteOffset {offset!r} in a view of byteStride {stride!r}")
        if offset + stride * (count - 1) + size > length:
            raise damaged(f"glTF accessor {a} reads {count:,} elements of {size} bytes from bufferView {v}, which holds "
                          f"{length:,} bytes")
        return np.ndarray((count, _GLTF_TYPE[etype]), dtype=np.dtype(_GLTF_DTYPE[ctype]), buffer=blob,
                          offset=start + offset, strides=(stride, _GLTF_COMPONENT[ctype]))

    for m, mesh in enumerate(items("meshes")):
        if not isinstance(mesh, dict):
            continue
        name = mesh.get("name", m)
        for k, prim in enumerate(mesh.get("primitives") or []):
            if not isinstance(prim, dict) or not isinstance(prim.get("attributes"), dict):
                continue
            position = prim["attributes"].get("POSITION")
            if position is None:
                continue
            points = read(position)
            n = int(accessors[position]["count"])
            if points is not None and not np.isfinite(points).all():
                raise InputError(f"@{path}@: glTF mesh {name!r}, primitive {k}: its positions (accessor {position}) "
                                 "hold NaN or infinite coordinates; fix them in the file.")
            for a in prim["attributes"].values():
                if a != position:
                    read(a)
            if prim.get("indices") is not None:
                index = read(prim["indices"])
                if index is not None and len(index) and int(index.max()) >= n:
                    raise damaged(f"glTF mesh {name!r}, primitive {k}: index {int(index.max())} (accessor "
                                  f"{prim['indices']}) is past its {n:,} positions")


#: Reads ``sys.argv[1]`` with pymeshlab and nothing else, in a process of its own (:func:`_probe`).
_PROBE = "import sys, pymeshlab\ntry:\n    pymeshlab.MeshSet().load_new_mesh(sys.argv[1])\nexcept Exception:\n    sys.exit(1)\n"


def _probe(path: Path) -> None:
    """Read the user's file once in a child process first: pymeshlab's readers trust what a file says (counts,
    indices, offsets), and a form :func:`check_file` does not know can still kill the process that reads it
    (SIGSEGV, or an abort on a corrupted heap) with no message. A child that dies so is an :class:`InputError`
    naming the file; one that fails politely leaves the message to the read here."""
    import signal
    import subprocess
    import sys

    try:
        r = subprocess.run([sys.executable, "-c", _PROBE, str(path)], stdin=subprocess.DEVNULL,
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    except OSError:  # no process to spare: read it here, as before
        return
    if r.returncode < 0:
        try:
            name = signal.Signals(-r.returncode).name
        except ValueError:
            name = f"signal {-r.returncode}"
        raise InputError(f"@{path}@: pymeshlab's reader crashed on this file ({name}): it is damaged, or holds counts "
                         "or indices its data does not back. Re-export it from the application that made it.")


def _load(pymeshlab, path: Path, ms=None, probe: bool = True):
    """``path`` read by pymeshlab into ``ms``; ``probe``: read it in a child first (:func:`_probe`), as for every
    file the user gave (the parts this module writes are read directly)."""
    if probe:
        _probe(path)
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
                    xyz = [float(w) for w in rest.split()[:3]]
                    if len(xyz) < 3 or not all(np.isfinite(xyz)):
                        raise ValueError(f"vertex {len(vertices) + 1} is {line.strip()!r}: 3 finite coordinates are needed")
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
            ms = _load(pymeshlab, part, probe=False)  # written here, from indices checked above
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
