"""Stage -> :class:`~foliage_tools.scene.model.Scene`.

Each unique prototype is read once: native instanceable references share their
USD prototype, point-instancer prototypes are read per prototype target, and
plain geometry is grouped by tree root (the nearest ``component`` model, else
the top-level prim). Invisible prims and ``guide``/``proxy`` purposes are
skipped. Geometry stays in the stage's units and axes.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from foliage_tools.geometry import upright
from foliage_tools.errors import InputError
from foliage_tools.scene import bakeable, dependencies, usd_diagnostics
from foliage_tools.geometry.leaves import face_values_from_triangles, leaf_components, triangulate
from foliage_tools.scene.model import Instance, Leaves, Light, MeshPart, Prototype, Scene
from foliage_tools.scene.schemas import LEAF_API, register

register()

from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdShade  # noqa: E402  (schemas must be registered first)

LEAF_NAME = re.compile(r"leaf|leaves|foliage|needle", re.IGNORECASE)
_WORDS = LEAF_NAME.pattern.split("|")
#: What makes a mesh a leaf mesh (:func:`classify_leaf`), in words for messages.
LEAF_MESH_RULE = (f"FoliageLeafAPI, primvars:foliage:isLeaf = true, or a name (or bound material's name) containing "
                  f"{', '.join(_WORDS[:-1])} or {_WORDS[-1]}")
SKIPPED_PURPOSES = (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy)


def open_stage(path: str | os.PathLike) -> Usd.Stage:
    """Open a USD file, turning every failure into an :class:`InputError` naming the file.

    Every layer the stage is made of is checked to be a regular file that USD can read before the stage is
    composed (``dependencies.open_layers``), so a FIFO or a device among them never blocks the run.
    """
    p = Path(path)
    name = dependencies.shown(p)
    bad_name = dependencies.name_problem(p)
    if bad_name is not None:
        raise InputError(f"@{name}@: {bad_name}, which USD cannot take in a file name. Rename the file.")
    problem = dependencies.file_problem(p)
    if problem == "does not exist":
        raise InputError(f"@{name}@: no such file. Check the path.")
    if problem == "is a directory, not a file":
        raise InputError(f"@{name}@ is a directory; give a USD file (.usd, .usda, .usdc, .usdz).")
    if problem is not None:  # a FIFO, socket or device (USD would block reading it), a symlink loop, no permission
        raise InputError(f"@{name}@ {problem}; give a USD file (.usd, .usda, .usdc, .usdz).")
    if p.stat().st_size == 0:
        raise InputError(f"@{p}@ is empty (0 bytes): an export or copy that did not finish? Export the asset again.")
    if not Sdf.FileFormat.FindByExtension(p.suffix.lstrip(".") or "none"):
        raise InputError(f"@{p}@: not a USD file (extension {p.suffix or 'none'!r}); give a .usd, .usda, .usdc or .usdz file.")
    try:
        held = dependencies.open_layers(p)  # noqa: F841  (held while the stage opens: USD reuses them)
    except InputError as exc:
        raise InputError(usd_diagnostics.relative_paths(str(exc), p)) from None
    # USD's own warnings (an unloadable sublayer or reference, with absolute paths) are logged, not printed: the
    # composition errors they repeat are reported in our words (bakeable.composition_problems, validate)
    covered: list[str] = []
    try:
        with usd_diagnostics.captured(covered):
            stage = Usd.Stage.Open(str(p), Usd.Stage.LoadAll)
            if stage is not None:
                covered.extend(str(e) for e in stage.GetCompositionErrors())
    except Tf.ErrorException as exc:
        undecodable = usd_diagnostics.not_utf8(p)
        if undecodable is not None:
            raise InputError(f"@{p}@ is not UTF-8 text ({undecodable}): USD text layers are UTF-8. Save the file as "
                             "UTF-8 (or export the asset again).") from None
        syntax = syntax_error(exc)
        if syntax is not None:
            file, line, column, what = syntax
            where = "" if Path(file).resolve() == p.resolve() else usd_diagnostics.relative_paths(f" (in @{file}@)", p)
            raise InputError(f"@{p}@, line {line}, column {column}{where}: not valid USD text: {what}. Fix the file "
                             "at that place (or export the asset again) and run the command again.") from None
        raise InputError(f"@{p}@: cannot be opened as USD ({usd_diagnostics.open_failure(exc, p)}). Is it a valid USD "
                         "file?") from None
    if stage is None:
        raise InputError(f"@{p}@: cannot be opened as USD. Is it a valid USD file?")
    return stage


#: The position USD's text parser gives a syntax error: ``FILE:LINE:COLUMN: what it expected``.
_SYNTAX_AT = re.compile(r"^(?P<file>.+?):(?P<line>\d+):(?P<column>\d+): (?P<what>.+)$", re.S)


def syntax_error(exc: Tf.ErrorException) -> tuple[str, int, int, str] | None:
    """(file, line, column, message) of the .usda syntax error among the errors of a failed open, else None: where
    the file needs fixing (:func:`usd_diagnostics.place_unclosed`), 1-based as editors count."""
    for error in exc.args:
        found = _SYNTAX_AT.match(usd_diagnostics.commentary(error))
        if found:
            what = " ".join(found["what"].split()).rstrip(".")
            line, column, what = usd_diagnostics.place_unclosed(found["file"], int(found["line"]), int(found["column"]), what)
            return found["file"], line, column, usd_diagnostics.without_cxx_names(what)
    return None


def _matrix(m: Gf.Matrix4d) -> np.ndarray:
    """USD's row-vector matrix -> column-vector numpy matrix."""
    return np.array(m, dtype=np.float64).T


def _transform_points(points: np.ndarray, m: np.ndarray) -> np.ndarray:
    return points @ m[:3, :3].T + m[:3, 3]


def classify_leaf(prim: Usd.Prim) -> tuple[bool, str]:
    """DESIGN.md section 3: FoliageLeafAPI; primvars:foliage:isLeaf; material or prim name; else wood."""
    if prim.HasAPI(LEAF_API):
        return True, "FoliageLeafAPI"
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("foliage:isLeaf")
    if pv and pv.HasAuthoredValue() and bakeable.leaf_flag_problem(prim, "") is None:  # else refused (attribute-types)
        value = pv.Get()
        if value is not None:
            flag = bool(np.asarray(value).reshape(-1)[0]) if np.ndim(value) else bool(value)
            return flag, "isLeaf primvar"
    material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
    if material and LEAF_NAME.search(material.GetPrim().GetName()):
        return True, "material"
    if LEAF_NAME.search(prim.GetName()):
        return True, "name"
    return False, "default"


def _is_skipped(prim: Usd.Prim, *, own_only: bool = False) -> bool:
    """An invisible prim or one of guide or proxy purpose (bakes leave it and its subtree out).

    ``own_only``: look at the prim's own visibility and purpose only, for a traversal that prunes every skipped
    prim's children (its ancestors were all looked at, and kept): computing them from the ancestors for every prim
    of such a traversal is quadratic in its depth (3,000 nested Xforms took minutes).
    """
    img = UsdGeom.Imageable(prim)
    if not img:
        return False
    if not own_only:
        return img.ComputeVisibility() == UsdGeom.Tokens.invisible or img.ComputePurpose() in SKIPPED_PURPOSES
    return img.GetVisibilityAttr().Get() == UsdGeom.Tokens.invisible or img.GetPurposeAttr().Get() in SKIPPED_PURPOSES


@dataclass
class _Reader:
    stage: Usd.Stage
    path: str
    xf: UsdGeom.XformCache = field(default_factory=UsdGeom.XformCache)
    prototypes: list[Prototype] = field(default_factory=list)
    instances: list[Instance] = field(default_factory=list)
    lights: list[Light] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    keys: dict[tuple[str, str], int] = field(default_factory=dict)
    instancer_sizes: dict[str, int] = field(default_factory=dict)
    empty_meshes: list[str] = field(default_factory=list)

    # -- meshes -----------------------------------------------------------
    def read_mesh(self, prim: Usd.Prim, to_proto: np.ndarray, *, editable: bool) -> MeshPart | None:
        pts, counts, idx = bakeable.mesh_arrays(prim)
        lacks = bakeable.mesh_lacks(pts, counts, idx)
        if lacks is not None:
            self.empty_meshes.append(f"mesh <{prim.GetPath()}> has {lacks}")
            self.warnings.append(f"@{self.path}@: mesh <{prim.GetPath()}> has {lacks}; skipped: give it points, face "
                                 "counts and face vertex indices, or remove it.")
            return None
        points = np.asarray(pts, dtype=np.float64)
        nonfinite = bakeable.nonfinite_points(str(prim.GetPath()), points)
        if nonfinite:
            raise InputError(f"@{self.path}@: {nonfinite}")
        counts = np.asarray(counts, dtype=np.int64)
        idx = np.asarray(idx, dtype=np.int64)
        broken = bakeable.topology_problem(str(prim.GetPath()), points.shape[0], counts, idx)
        if broken:
            raise InputError(f"@{self.path}@: mesh {broken}")
        tris, face_of_tri = triangulate(counts, idx)
        is_leaf, reason = classify_leaf(prim)
        placed = _transform_points(points, to_proto)
        if is_leaf:
            _refuse([bakeable.leaf_area_problem(str(prim.GetPath()), placed, tris, self.path)])
        return MeshPart(
            path=str(prim.GetPath()),
            points=placed,
            triangles=tris,
            face_of_triangle=face_of_tri,
            face_count=int(counts.shape[0]),
            is_leaf=is_leaf,
            leaf_reason=reason,
            editable=editable,
        )

    def read_prototype(self, root: Usd.Prim, *, path: str, kind: str, root_xform: np.ndarray, mesh_prims=None) -> int:
        """Read the meshes under ``root`` into a Prototype; return its index."""
        editable = kind != "instance"
        if mesh_prims is None:
            mesh_prims = []
            it = iter(Usd.PrimRange(root))
            for prim in it:
                if _is_skipped(prim, own_only=prim != root):
                    it.PruneChildren()
                    continue
                if prim.IsInstance() or prim.IsA(UsdGeom.PointInstancer):
                    # below the prototype's own path (a native prototype's: its first instance's), not USD's </__Prototype_N>
                    at = path + str(prim.GetPath())[len(str(root.GetPath())):]
                    self.warnings.append(
                        (f"@{self.path}@: prototype <{path}> is itself a point instancer; its instances are not read"
                         if prim == root else
                         f"@{self.path}@: nested instancing at <{at}> inside prototype <{path}> is not read")
                        + ": " + bakeable.NESTED_INSTANCING_FIX
                    )
                    it.PruneChildren()
                    continue
                if prim.IsA(UsdGeom.Mesh):
                    _refuse([bakeable.attribute_type_problem(prim, self.path)])
                    mesh_prims.append(prim)
        inv_root = None
        if kind == "prim":
            root_world = _matrix(self.xf.GetLocalToWorldTransform(root))
            _refuse([bakeable.transform_problem(root, root_world, self.path)])
            inv_root = np.linalg.inv(root_world)
        parts = []
        for prim in mesh_prims:
            if kind == "prim":
                world = _matrix(self.xf.GetLocalToWorldTransform(prim))
                _refuse([bakeable.transform_problem(prim, world, self.path)])
                to_proto = inv_root @ world
            else:
                rel, _ = self.xf.ComputeRelativeTransform(prim, root)
                to_proto = root_xform @ _matrix(rel)
                _refuse([bakeable.transform_problem(prim, to_proto, self.path)])
            part = self.read_mesh(prim, to_proto, editable=editable)
            if part is not None:
                parts.append(part)
        leaf_points = [m.points[np.unique(m.triangles)] for m in parts if m.is_leaf and len(m.triangles)]
        if leaf_points:  # before its leaves are found: welding points of a grid no bake can store is meaningless
            pts = np.concatenate(leaf_points)
            _refuse([bakeable.grid_scale_problem(path, np.stack([pts.min(axis=0), pts.max(axis=0)]), self.path)])
        leaves, degenerate = _leaves(parts)
        name = Path(path).name or "root"
        self.prototypes.append(
            Prototype(path=path, name=name, meshes=tuple(parts), leaves=leaves, kind=kind, degenerate_triangles=degenerate)
        )
        return len(self.prototypes) - 1

    # -- traversal ----------------------------------------------------------
    def tree_root(self, prim: Usd.Prim) -> Usd.Prim:
        top = prim
        p = prim
        while p and not p.IsPseudoRoot():
            if Usd.ModelAPI(p).GetKind() == "component":
                return p
            top = p
            p = p.GetParent()
        return top

    def run(self) -> Scene:
        plain: dict[str, list[Usd.Prim]] = {}
        it = iter(Usd.PrimRange(self.stage.GetPseudoRoot()))
        next(it)  # the pseudo-root
        for prim in it:
            if _is_skipped(prim, own_only=True):  # (the traversal prunes skipped prims' children)
                it.PruneChildren()
                continue
            _refuse([bakeable.attribute_type_problem(prim, self.path)])
            if prim.IsA(UsdGeom.PointInstancer):
                self.point_instancer(UsdGeom.PointInstancer(prim))
                it.PruneChildren()
            elif prim.IsInstance():
                self.native_instance(prim)
                it.PruneChildren()
            elif prim.IsA(UsdGeom.Mesh):
                plain.setdefault(str(self.tree_root(prim).GetPath()), []).append(prim)
            elif prim.IsA(UsdLux.DistantLight) or prim.IsA(UsdLux.DomeLight):
                self.light(prim)
        for root_path, meshes in plain.items():
            root = self.stage.GetPrimAtPath(root_path)
            k = self.read_prototype(root, path=root_path, kind="prim", root_xform=np.eye(4), mesh_prims=meshes)
            m = _matrix(self.xf.GetLocalToWorldTransform(root))
            self.instances.append(Instance(prototype=k, path=root_path, transform=m))
        up = UsdGeom.GetStageUpAxis(self.stage)
        mpu = float(UsdGeom.GetStageMetersPerUnit(self.stage))
        dp = self.stage.GetDefaultPrim()
        return Scene(
            path=self.path,
            up_axis=str(up),
            meters_per_unit=mpu,
            prototypes=tuple(self.prototypes),
            instances=tuple(self.instances),
            lights=tuple(self.lights),
            default_prim=str(dp.GetPath()) if dp else None,
            default_prim_transform=_matrix(self.xf.GetLocalToWorldTransform(dp)) if dp else np.eye(4),
            instancer_sizes=dict(self.instancer_sizes),
            empty_meshes=tuple(self.empty_meshes),
        )

    def native_instance(self, prim: Usd.Prim) -> None:
        proto = prim.GetPrototype()
        key = ("instance", str(proto.GetPath()))
        if key not in self.keys:
            self.keys[key] = self.read_prototype(proto, path=str(prim.GetPath()), kind="instance", root_xform=np.eye(4))
        world = _matrix(self.xf.GetLocalToWorldTransform(prim))
        _refuse([bakeable.transform_problem(prim, world, self.path)])
        self.instances.append(Instance(prototype=self.keys[key], path=str(prim.GetPath()), transform=world))

    def point_instancer(self, pi: UsdGeom.PointInstancer) -> None:
        prim = pi.GetPrim()
        targets = pi.GetPrototypesRel().GetTargets()
        t = Usd.TimeCode.Default()
        # IgnoreMask keeps the transforms aligned with protoIndices (DESIGN.md section 5); mask applied below.
        xforms = pi.ComputeInstanceTransformsAtTime(
            t, t, UsdGeom.PointInstancer.IncludeProtoXform, UsdGeom.PointInstancer.IgnoreMask
        )
        proto_indices = pi.GetProtoIndicesAttr().Get(t)
        if proto_indices is None or xforms is None:
            self.warnings.append(f"@{self.path}@: point instancer <{prim.GetPath()}> has no protoIndices; skipped: "
                                 "author protoIndices, one prototype index per instance.")
            return
        proto_indices = np.asarray(proto_indices, dtype=np.int64)
        self.instancer_sizes[str(prim.GetPath())] = int(proto_indices.size)
        mask = np.asarray(pi.ComputeMaskAtTime(t) or [True] * len(proto_indices), dtype=bool)
        # invisibleIds hides instances from renderers (UsdGeomPointInstancer): they neither receive nor block light
        invisible = np.asarray(pi.GetInvisibleIdsAttr().Get(t) or [], dtype=np.int64)
        ids = np.asarray(pi.GetIdsAttr().Get(t) or np.arange(len(proto_indices)), dtype=np.int64)
        if invisible.size and ids.size == mask.size:
            mask &= ~np.isin(ids, invisible)
        world = _matrix(self.xf.GetLocalToWorldTransform(prim))
        _refuse(list(bakeable.instancer_problems(prim, world, self.path)))
        proto_ids: dict[int, int] = {}
        for j, target in enumerate(targets):
            p = self.stage.GetPrimAtPath(target)
            if not p:
                raise InputError(f"@{self.path}@: point instancer <{prim.GetPath()}> names a missing prototype <{target}>.")
            # with IncludeProtoXform the prototype root's own transform is in `xforms`, so geometry is
            # read relative to the root; an instanceable prototype shares its native prototype with
            # every other instance of the same asset (read once).
            if p.IsInstance():
                key = ("instance", str(p.GetPrototype().GetPath()))
                if key not in self.keys:
                    self.keys[key] = self.read_prototype(p.GetPrototype(), path=str(target), kind="instance", root_xform=np.eye(4))
            else:
                key = ("pointinstancer", str(target))
                if key not in self.keys:
                    self.keys[key] = self.read_prototype(p, path=str(target), kind="pointinstancer", root_xform=np.eye(4))
            proto_ids[j] = self.keys[key]
        mats = world @ np.transpose(np.array(xforms, dtype=np.float64).reshape(-1, 4, 4), (0, 2, 1))  # all at once
        base = str(prim.GetPath())
        for i in np.flatnonzero(mask & np.isin(proto_indices, list(proto_ids))):
            self.instances.append(Instance(prototype=proto_ids[int(proto_indices[i])], path=f"{base}[{i}]", transform=mats[i]))

    def light(self, prim: Usd.Prim) -> None:
        light = read_light(prim, self.xf.GetLocalToWorldTransform(prim), self.path)
        if light is not None:
            self.lights.append(light)


def read_light(prim: Usd.Prim, world: Gf.Matrix4d, path: str) -> Light | None:
    """A DistantLight (the sun) or DomeLight (the sky) as the bakes use it, from its world transform; None for
    other prims. :class:`InputError` for a sun that points nowhere and a light of NaN, infinite or negative
    intensity or colour (``bakeable``: validate's transforms and lights rules say the same)."""
    if not (prim.IsA(UsdLux.DistantLight) or prim.IsA(UsdLux.DomeLight)):
        return None
    m = _matrix(world)
    if prim.IsA(UsdLux.DistantLight):
        _refuse([bakeable.light_problem(prim, m, path)])
    _refuse([bakeable.light_value_problem(prim, path)])
    intensity, color = bakeable.light_values(prim)
    if prim.IsA(UsdLux.DistantLight):
        d = m[:3, 2]  # the light travels along its -Z axis, so +Z points toward the sun
        kind = "distant"
    else:
        up = UsdGeom.GetStageUpAxis(prim.GetStage())
        d = np.array([0.0, 1.0, 0.0]) if up == "Y" else np.array([0.0, 0.0, 1.0])
        kind = "dome"
    n = np.linalg.norm(d)
    return Light(path=str(prim.GetPath()), kind=kind, direction=d / n if n else d, intensity=intensity, color=color)


class Refused(InputError):
    """A reader's refusal of one of ``bakeable``'s problems: :class:`InputError` (exit 2) with the problem's rule."""

    def __init__(self, message: str, rule: str, prim: str = "") -> None:
        super().__init__(message)
        self.rule = rule
        self.prim = prim


def _refuse(problems) -> None:
    """Raise the first of ``bakeable``'s problems (None entries ignored) as an :class:`InputError`."""
    found = [p for p in problems if p is not None]
    if found:
        more = f" ({len(found) - 1} more such problem(s): `foliage validate` lists them.)" if len(found) > 1 else ""
        raise Refused(found[0].message + more, found[0].rule, found[0].prim)


def _leaves(parts: list[MeshPart]) -> tuple[Leaves, int]:
    centers, normals, areas, mesh_index, face_ids = [], [], [], [], []
    offset = 0
    degenerate = 0
    for i, part in enumerate(parts):
        if not part.is_leaf:
            face_ids.append(np.full(part.face_count, -1, dtype=np.int64))
            continue
        comp = leaf_components(part.points, part.triangles)
        degenerate += comp.degenerate
        tri_leaf = np.where(comp.triangle_leaf >= 0, comp.triangle_leaf + offset, -1)
        face_ids.append(face_values_from_triangles(part.face_of_triangle, tri_leaf, part.face_count))
        centers.append(comp.centers)
        normals.append(comp.normals)
        areas.append(comp.areas)
        mesh_index.append(np.full(comp.areas.shape[0], i, dtype=np.int64))
        offset += comp.areas.shape[0]
    if centers:
        leaves = Leaves(
            np.concatenate(centers), np.concatenate(normals), np.concatenate(areas), np.concatenate(mesh_index), tuple(face_ids)
        )
    else:
        z = np.zeros((0, 3))
        leaves = Leaves(z, z, np.zeros(0), np.zeros(0, dtype=np.int64), tuple(face_ids))
    return leaves, degenerate


def read_scene(path: str | os.PathLike) -> tuple[Scene, list[str]]:
    """Read a USD file into a :class:`Scene`.

    Returns
    -------
    scene : Scene
    warnings : list of str
        Things skipped or suspicious, for the command's report.

    Raises
    ------
    InputError
        Missing file, not USD, an unloadable sublayer or reference, an empty stage, a unit that is not
        positive, NaN points, broken topology, a transform that collapses or overflows, a leaf mesh
        of zero area (``scene.bakeable``: the checks ``foliage validate`` reports as errors).
    """
    return read_stage(open_stage(path), str(path))


def read_stage(stage: Usd.Stage, path: str) -> tuple[Scene, list[str]]:
    """:func:`read_scene` of a stage already open (``validate`` reads the stage it checks with it, so whatever a
    bake refuses, validate reports)."""
    try:
        _refuse(list(bakeable.composition_problems(stage, path)))
        if not any(True for _ in stage.GetPseudoRoot().GetChildren()):
            raise InputError(f"@{path}@: the stage is empty (no prims). Is this the right file?")
        _refuse(list(bakeable.stage_problems(stage, path)))
        _refuse(list(bakeable.volume_problems(stage, path)))
        reader = _Reader(stage=stage, path=path)
        scene = reader.run()
    except Tf.ErrorException as exc:
        # USD could not compute something it was asked for (an xformOp it does not know): the prim whose own
        # values do it, in validate's words, else what USD said
        _refuse(bakeable.usd_error_problems(stage, path))
        raise InputError(f"@{path}@: USD cannot read the stage ({usd_diagnostics.open_failure(exc, path)}). Run "
                         "`foliage validate` on it, and fix or re-export the asset.") from None
    for proto in scene.prototypes:
        if proto.degenerate_triangles:
            reader.warnings.append(
                f"{path}: prototype <{proto.path}> has {proto.degenerate_triangles} degenerate (zero-area) leaf triangle(s); they were ignored."
            )
    _refuse([_placement_problem(scene, path)])
    reader.warnings += sideways_warnings(scene, path)
    return scene, reader.warnings


def _placement_problem(scene: Scene, path: str) -> bakeable.Problem | None:
    """The first instance too far from the origin for single precision to hold its leaves
    (:func:`bakeable.placement_precision_problem`)."""
    if not scene.instances:
        return None
    size = [float(np.sqrt(np.median(p.leaves.areas))) if p.leaves.count else 0.0 for p in scene.prototypes]
    boxes = [p.bounds(leaves_only=True) if p.leaves.count else None for p in scene.prototypes]
    for inst in scene.instances:
        box = boxes[inst.prototype]
        if box is None:
            continue
        m = inst.transform
        scale = abs(float(np.linalg.det(m[:3, :3]))) ** (1.0 / 3.0)
        corners = np.array([[x, y, z] for x in box[:, 0] for y in box[:, 1] for z in box[:, 2]]) @ m[:3, :3].T + m[:3, 3]
        problem = bakeable.placement_precision_problem(inst.path, size[inst.prototype] * scale,
                                                       float(np.abs(corners).max()), path)
        if problem is not None:
            return problem
    return None


#: The start of :func:`sideways_warnings`' text (``validate`` reports it as its ``upright`` rule).
SIDEWAYS = "lies on its side"


def sideways_warnings(scene: Scene, path: str) -> list[str]:
    """A warning for each prototype whose trunk shows that, placed where its first instance stands, it stands along
    another axis than the stage's ``upAxis`` (:func:`foliage_tools.geometry.upright.stands_along`, by the trunk
    alone): the bakes' sun and sky would then light it from the side."""
    out = []
    for i, proto in enumerate(scene.prototypes):
        placed = next((inst.transform for inst in scene.instances if inst.prototype == i), None)
        if placed is None or not proto.meshes:
            continue
        linear, offset = placed[:3, :3].T, placed[:3, 3]  # world = M p (column vectors)
        every = [m.points @ linear + offset for m in proto.meshes if len(m.points)]
        leaves = [m.points @ linear + offset for m in proto.meshes if m.is_leaf and len(m.points)]
        if not every or not leaves:
            continue
        found, why = upright.stands_along(np.concatenate(every), np.concatenate(leaves), trunk_only=True)
        if found is not None and found != f"+{scene.up_axis}":
            fix = (f"set the stage's upAxis to {found[1]} (`foliage import --up-axis {found[1]}` for an imported mesh)"
                   if found[0] == "+" and found[1] in "YZ" else "turn it upright in a DCC")
            out.append(f"@{path}@: the tree <{proto.path}> {SIDEWAYS}: it stands along {found} ({why}), but the "
                       f"stage's upAxis is {scene.up_axis}, so the bakes light it from the side. {fix[0].upper()}{fix[1:]}.")
    return out
