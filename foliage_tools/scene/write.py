"""Write a stage's results: an output layer that sublayers the input, plus ``.vdb`` grids.

The layer holds only what the stage computed (overs for primvars, new
``FoliageLighting`` volumes), copies the input's ``upAxis``,
``metersPerUnit`` and ``defaultPrim`` (stage metadata is read from the root
layer only), and refers to the input and the grids by relative paths. All
files of a stage are written atomically together.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from foliage_tools.errors import OutputError
from foliage_tools.scene.atomic import atomic_outputs, check_name_fits, check_writable, recover, refuse_link_loop
from foliage_tools.scene.dependencies import dependencies
from foliage_tools.scene.integrity import locator, new_commit_id, seal, utc_now
from foliage_tools.scene.schemas import LIGHTING_API, register
from foliage_tools.scene.vdb import Grid, write_vdb

register()

from pxr import Gf, Sdf, Usd, UsdGeom, UsdVol, Vt  # noqa: E402

USD_EXTENSIONS = (".usda", ".usdc", ".usd")
#: ``--volume-purpose`` of the stages that write grids: ``default`` loads in DCCs (issue #17); ``guide`` keeps the
#: volume out of default imports and renders, as before issue #17.
VOLUME_PURPOSES = ("default", "guide")

_PRIMVAR_TYPES = {
    "int": (Sdf.ValueTypeNames.IntArray, Vt.IntArray),
    "float": (Sdf.ValueTypeNames.FloatArray, Vt.FloatArray),
    "color3f": (Sdf.ValueTypeNames.Color3fArray, Vt.Vec3fArray),
}


@dataclass(frozen=True)
class PrimvarEdit:
    prim: str
    name: str
    """Without the ``primvars:`` prefix, e.g. ``foliage:leafId``."""
    values: np.ndarray
    type: str
    """``int``, ``float`` or ``color3f``."""
    interpolation: str = "uniform"
    element_size: int = 1


@dataclass(frozen=True)
class VolumeEdit:
    path: str
    """Prim path of the ``UsdVol.Volume`` (``<tree>/FoliageLighting``)."""
    vdb_file: Path
    """Final path of the ``.vdb`` (beside the layer)."""
    grids: tuple[Grid, ...]
    attributes: dict = field(default_factory=dict)
    """``foliage:*`` attribute values of FoliageLightingAPI."""
    purpose: str = "default"
    """The volume's purpose (``--volume-purpose``): ``default`` (DCCs import it and renderers draw it) or ``guide``."""
    transform: np.ndarray | None = None
    """(4, 4) parent-from-volume matrix (column-vector convention) authored as the volume's xform; None: none."""
    class_prim: str | None = None
    """An ancestor of ``path`` authored as a USD ``class`` (an abstract Xform): the volume is then a prototype,
    not drawn where it is authored (abstract prims are not traversed by default), that ``placements`` reference;
    None: the volume is an ordinary prim."""
    placements: tuple[VolumePlacement, ...] = ()
    """Prims that reference ``class_prim`` (an internal reference) with their own transform: each shows the volume
    over one instance, sharing its fields and ``.vdb`` file."""

    def __post_init__(self) -> None:
        if self.purpose not in VOLUME_PURPOSES:
            raise ValueError(f"volume purpose must be one of {', '.join(VOLUME_PURPOSES)}, got {self.purpose!r}")
        inside = self.class_prim is not None and Sdf.Path(self.path).HasPrefix(Sdf.Path(self.class_prim))
        if self.class_prim is not None and (self.class_prim == self.path or not inside):
            raise ValueError(f"class_prim <{self.class_prim}> must be an ancestor of the volume <{self.path}>")
        if self.placements and self.class_prim is None:
            raise ValueError(f"the volume <{self.path}> has placements but no class_prim for them to reference")


@dataclass(frozen=True)
class VolumePlacement:
    """One placed copy of a ``VolumeEdit``'s class: a prim that references it, over one instance."""

    path: str
    """Prim path of the placing prim (an Xform; the volume lands at ``path`` + the volume's path below the class)."""
    transform: np.ndarray
    """(4, 4) parent-from-prototype matrix (column-vector convention), authored as the prim's one xformOp."""
    instance: str
    """The instance it lies over (a prim path, or ``<instancer>[i]``), authored as ``foliage:instance``."""


@dataclass(frozen=True)
class AttributeEdit:
    prim: str
    api: str | None
    values: dict
    """name -> (value, Sdf type name string, e.g. 'float')."""


@dataclass
class LayerEdits:
    primvars: list[PrimvarEdit] = field(default_factory=list)
    volumes: list[VolumeEdit] = field(default_factory=list)
    attributes: list[AttributeEdit] = field(default_factory=list)


def input_files(input_path: Path) -> frozenset[Path]:
    """Every file the input stage reads: its layers (sublayers, references, payloads) and assets (``.vdb`` grids, ...).

    ``UsdUtils.ComputeAllDependencies`` opens the layers without composing the
    stage. Resolved absolute paths; cached per path and modification time.
    """
    p = Path(input_path).resolve()
    try:
        mtime = p.stat().st_mtime_ns
    except OSError:
        return frozenset()
    return _input_files(p, mtime)


@lru_cache(maxsize=8)
def _input_files(path: Path, _mtime: int) -> frozenset[Path]:
    return dependencies(path)[0]


def missing_inputs(input_path: Path) -> tuple[str, ...]:
    """Asset paths the input's layers name that resolve to no file (e.g. a deleted upstream ``.vdb``), as authored."""
    p = Path(input_path).resolve()
    try:
        mtime = p.stat().st_mtime_ns
    except OSError:
        return ()
    return _missing_inputs(p, mtime)


@lru_cache(maxsize=8)
def _missing_inputs(path: Path, _mtime: int) -> tuple[str, ...]:
    return dependencies(path)[1]


def check_output_path(input_path: Path, out: Path, extra_outputs=(), *, writes_grids: bool = True,
                      warnings: list[str] | None = None) -> None:
    """Refuse outputs that would destroy the input or cannot be written; tidy up after killed runs on this output.

    The input is every file its stage reads, not only the named layer: writing
    over a sublayer (``foliage spp a.lb.usda -o a.density.usda``, where
    a.lb.usda sublayers a.density.usda) or a ``.vdb`` the input uses would change
    the input, and could make the layer stack a cycle. ``extra_outputs``: the
    ``.vdb`` files the stage will write; before they are known, any ``.vdb`` the
    input uses that is named like this output's grids (``OUT.vdb``,
    ``OUT.NN_name.vdb``) is refused when ``writes_grids`` (the stage will write
    grids whose names are not known yet).

    With ``warnings``, what killed runs left for this output is finished or
    removed (``atomic.recover``) and noted there.
    """
    if out.suffix not in USD_EXTENSIONS:
        raise OutputError(f"@{out}@: the output must be a USD layer ({', '.join(USD_EXTENSIONS)}).")
    refuse_link_loop(out)  # before resolving it
    if out.parent.is_dir():
        check_name_fits(out)
    if out.resolve() == Path(input_path).resolve():
        raise OutputError(f"@{out}@ is the input file; choose another output (inputs are never modified).")
    used = input_files(input_path)
    target = out.resolve()
    grids = [Path(e).resolve() for e in extra_outputs]
    grid_name = re.compile(re.escape(target.stem) + r"(\.\d\d_[A-Za-z0-9_]+)?\.vdb")  # pipeline.density.vdb_path
    if writes_grids:
        grids += [f for f in used if f.parent == target.parent and grid_name.fullmatch(f.name)]
    for f in [target, *grids]:
        if f in used:
            what = "this output" if f == target else f"its grid file {f.name}"
            raise OutputError(
                f"@{out}@: {what} is a file the input @{input_path}@ uses (through its sublayers, references or "
                "grids); writing it would change the input. Choose another output path (inputs are never modified)."
            )
    if writes_grids or grids:
        _refuse_a_siblings_grids(out, grid_name)
    check_writable(out)
    if warnings is not None:
        recover(out.parent, [out.name], warnings)


def _refuse_a_siblings_grids(out: Path, grid_name: re.Pattern) -> None:
    """``OUT.usd`` and ``OUT.usda`` name their grid files alike (``pipeline.density.vdb_path``): writing one beside
    the other's result would overwrite that result's grids, which its layer then refuses as stale."""
    if not out.parent.is_dir():
        return
    siblings = [out.with_suffix(ext) for ext in USD_EXTENSIONS if ext != out.suffix and out.with_suffix(ext).exists()]
    taken = sorted(f.name for f in out.parent.iterdir() if grid_name.fullmatch(f.name))
    if siblings and taken:
        raise OutputError(
            f"@{out}@: @{siblings[0]}@ is already beside it, and the grid files of both are named {out.stem}.vdb "
            f"(there now: {', '.join(taken[:3])}); writing this output would overwrite that result's grids. Choose "
            f"another output name, or remove @{siblings[0]}@ and its grids first.")


def _relative(target: Path, start_dir: Path, *, own_name: bool = False) -> str:
    """``target`` relative to ``start_dir`` (``./x`` or ``../x``), symbolic links resolved.

    ``own_name``: a symbolic link at ``target`` itself is not followed (the folders above it are). An output is
    named so: the commit replaces a link at an output's name by the file itself, so the link's target is neither
    written nor named (an input keeps its resolved path: its own relative asset paths hold from there)."""
    target = Path(target)
    where = target.parent.resolve() / target.name if own_name else target.resolve()
    rel = os.path.relpath(where, start_dir.resolve())
    return rel if rel.startswith(".") else f"./{rel}"


def _set_attr(prim: Usd.Prim, name: str, value, type_name: str) -> None:
    attr = prim.CreateAttribute(name, getattr(Sdf.ValueTypeNames, type_name))
    attr.Set(value)


def write_layer(input_path: Path, out: Path, edits: LayerEdits, *, input_stage_meta: dict) -> list[Path]:
    """Write the output layer and its grid files as one result (``atomic``); return the paths written.

    The layer records the content hash of each grid file and of its input
    when that is a foliage layer itself (``integrity``), so a layer and a
    grid from different runs are refused by ``validate`` and by later stages.
    """
    input_path = Path(input_path)
    out = Path(out)
    vdb_files = [v.vdb_file for v in edits.volumes]
    check_output_path(input_path, out, vdb_files, writes_grids=False)  # the exact grid files, no prediction
    if len(set(vdb_files)) != len(vdb_files):
        raise ValueError("each volume needs its own .vdb file")
    for f in vdb_files:
        check_name_fits(f)
    with atomic_outputs([*vdb_files, out]) as temps:
        commit = new_commit_id()
        meta = {"creator": "foliage-tools", "foliage:commit": commit, "foliage:written": utc_now()}  # integrity.written
        tmp = temps[out]
        layer = Sdf.Layer.CreateNew(str(tmp))
        if layer is None:  # pragma: no cover - CreateNew raises on failure in practice
            raise OutputError(f"@{out}@: cannot create the layer.")
        # composed from the staging directory while authoring (so overs land on the input's prims as before);
        # the path written is the one relative to the layer's final place
        layer.subLayerPaths.append(_relative(input_path, tmp.parent))
        for key in ("upAxis", "metersPerUnit", "defaultPrim"):
            if input_stage_meta.get(key) is not None:
                layer.pseudoRoot.SetInfo(key, input_stage_meta[key])
        stage = Usd.Stage.Open(layer)
        stage.SetEditTarget(Usd.EditTarget(layer))
        carried = {vol.path: _earlier_fields(stage, vol) for vol in edits.volumes}
        for vol in edits.volumes:
            write_vdb(temps[vol.vdb_file], list(vol.grids), metadata=meta,
                      carried=[(f.file, f.grid) for f in carried[vol.path]])
        _author(stage, edits, out, carried)
        del stage
        layer.subLayerPaths[0] = _relative(input_path, out.parent)
        seal(layer, locator(tmp.parent, out.parent), commit)
        layer.Save()
    return [*vdb_files, out]


@dataclass(frozen=True)
class _EarlierField:
    """A field of the input's volume that this stage does not rewrite: its grid is copied into this stage's file."""

    prim: str
    file: Path
    grid: str


def _earlier_fields(stage: Usd.Stage, vol: VolumeEdit) -> list[_EarlierField]:
    """The fields an earlier stage gave the volume at ``vol.path`` (composed from the input), other than ``vol``'s grids.

    One ``.vdb`` per volume (issue #17): Blender 5.0 reads a single file per
    Volume prim (the last field's) and drops the grids of the others, so each
    stage copies the earlier grids into its own file and points their fields
    at it; the earlier files stay as the earlier layers wrote them. A field
    whose file is missing is left alone (``validate`` names it).
    """
    prim = stage.GetPrimAtPath(vol.path)
    volume = UsdVol.Volume(prim) if prim else None
    if not volume:
        return []
    new = {g.name for g in vol.grids}
    found = []
    for name, field_path in sorted(volume.GetFieldPaths().items()):
        asset = UsdVol.OpenVDBAsset(stage.GetPrimAtPath(field_path))
        if not asset:
            continue
        grid = asset.GetFieldNameAttr().Get() or str(name)
        if str(name) in new or grid in new:
            continue  # this stage writes that grid anew
        ap = asset.GetFilePathAttr().Get()
        if ap is None or not ap.resolvedPath or not Path(ap.resolvedPath).is_file():
            continue
        found.append(_EarlierField(str(field_path), Path(ap.resolvedPath), grid))
    return found


def _mark_custom(prim: Usd.Prim, attr: Usd.Attribute) -> None:
    """Author ``custom`` on the attribute's spec in the edit target, schema-defined or not.

    DCC importers keep custom attributes only (Blender 5.0's USD import drops
    the attributes an applied API schema defines, such as ``foliage:tau``);
    USD itself reads the values the same either way.
    """
    spec = prim.GetStage().GetEditTarget().GetPropertySpecForScenePath(attr.GetPath())
    if spec is not None and not spec.custom:
        spec.custom = True


def _apply_lighting_metadata(prim: Usd.Prim, attributes: dict) -> None:
    prim.ApplyAPI(LIGHTING_API)
    for name, value in attributes.items():
        attr = prim.GetAttribute(name)
        if not attr:
            raise ValueError(f"{name} is not an attribute of {LIGHTING_API}")
        if isinstance(value, (tuple, list)):  # e.g. int3 -> Gf.Vec3i
            value = attr.GetTypeName().type.pythonClass(*value)
        attr.Set(value)
        _mark_custom(prim, attr)


def _author(stage: Usd.Stage, edits: LayerEdits, out: Path, carried: dict[str, list[_EarlierField]]) -> None:
    for pv in edits.primvars:
        prim = stage.OverridePrim(pv.prim)
        sdf_type, vt = _PRIMVAR_TYPES[pv.type]
        primvar = UsdGeom.PrimvarsAPI(prim).CreatePrimvar(pv.name, sdf_type, pv.interpolation, pv.element_size)
        values = np.ascontiguousarray(pv.values)
        if pv.type == "int":
            values = values.astype(np.int32)
        else:
            values = values.astype(np.float32)
        primvar.Set(vt.FromNumpy(values))
    for vol in edits.volumes:
        if vol.class_prim is not None:  # first, so the volume's Define finds a defined ancestor and adds no `def` for it
            _define_scopes(stage, Sdf.Path(vol.class_prim).GetParentPath())
            cls = stage.DefinePrim(vol.class_prim, "Xform")
            cls.SetSpecifier(Sdf.SpecifierClass)
        volume = UsdVol.Volume.Define(stage, vol.path)
        # purpose default unless --volume-purpose guide (issue #17): DCCs import and renderers draw only
        # default/render purpose by default (Blender 5.0 skipped the volume when it was a guide)
        volume.CreatePurposeAttr(UsdGeom.Tokens.default_ if vol.purpose == "default" else UsdGeom.Tokens.guide)
        if vol.transform is not None:  # Gf matrices are row-vector: the transpose of ours
            volume.AddTransformOp().Set(Gf.Matrix4d(np.asarray(vol.transform, dtype=np.float64).T.tolist()))
        lo = np.min([np.asarray(g.origin) for g in vol.grids], axis=0)
        hi = np.max([np.asarray(g.origin) + np.asarray(g.values.shape[:3]) * g.voxel_size for g in vol.grids], axis=0)
        volume.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([lo, hi]).astype(np.float32)))
        rel_file = _relative(vol.vdb_file, out.parent, own_name=True)
        fields = []
        for g in vol.grids:
            field_path = Sdf.Path(vol.path).AppendChild(g.name)
            asset = UsdVol.OpenVDBAsset.Define(stage, field_path)
            asset.CreateFilePathAttr(Sdf.AssetPath(rel_file))
            asset.CreateFieldNameAttr(g.name)
            asset.CreateFieldDataTypeAttr(g.data_type)
            volume.CreateFieldRelationship(g.name, field_path)
            _hide_field(asset)
            fields.append(asset.GetPrim())
        for earlier in carried.get(vol.path, ()):
            asset = UsdVol.OpenVDBAsset(stage.OverridePrim(earlier.prim))
            asset.CreateFilePathAttr(Sdf.AssetPath(rel_file))
            _hide_field(asset)
        # the volume's metadata is the last stage's (stages chained over one volume override it);
        # each field carries the metadata of the stage that wrote its grid, which nothing overrides
        for prim in [volume.GetPrim(), *fields]:
            _apply_lighting_metadata(prim, vol.attributes)
        for placement in vol.placements:
            assert vol.class_prim is not None  # VolumeEdit refuses placements without one
            _place(stage, vol.class_prim, placement)
    for edit in edits.attributes:
        prim = stage.OverridePrim(edit.prim)
        if edit.api:
            prim.ApplyAPI(edit.api)
        for name, (value, type_name) in edit.values.items():
            _set_attr(prim, name, value, type_name)
            _mark_custom(prim, prim.GetAttribute(name))


def _define_scopes(stage: Usd.Stage, path: Sdf.Path) -> None:
    """``path`` and its ancestors as ``Scope`` where the stage has no prim yet (no transform, nothing drawn)."""
    for p in path.GetPrefixes():
        if not stage.GetPrimAtPath(p):
            UsdGeom.Scope.Define(stage, p)


def _place(stage: Usd.Stage, class_prim: str, placement: VolumePlacement) -> None:
    """The placing prim of one instance: an internal reference to the class, and the instance's transform.

    The fields, their grids and their ``.vdb`` come through the reference, so
    a later stage's grids reach every placement without touching it: a
    placement the input already has, the same (an earlier stage wrote it), is
    not authored again (16 placements are ~9 kB of ``.usda`` a layer). One
    that differs (the instances moved since) is authored whole, an explicit
    reference list and a fresh xformOpOrder, so it is this stage's, not a mix
    with the earlier layer's.
    """
    path = Sdf.Path(placement.path)
    if _placed_already(stage, class_prim, placement):
        return
    _define_scopes(stage, path.GetParentPath())
    prim = stage.DefinePrim(path, "Xform")
    prim.GetReferences().SetReferences([Sdf.Reference(primPath=Sdf.Path(class_prim))])
    op = UsdGeom.Xformable(prim).MakeMatrixXform()  # Gf matrices are row-vector: the transpose of ours
    op.Set(Gf.Matrix4d(np.asarray(placement.transform, dtype=np.float64).T.tolist()))
    _set_attr(prim, "foliage:instance", placement.instance, "String")
    _mark_custom(prim, prim.GetAttribute("foliage:instance"))


def _placed_already(stage: Usd.Stage, class_prim: str, placement: VolumePlacement) -> bool:
    prim = stage.GetPrimAtPath(placement.path)
    if not prim or prim.GetAttribute("foliage:instance").Get() != placement.instance:
        return False
    arcs = Usd.PrimCompositionQuery.GetDirectReferences(prim).GetCompositionArcs()
    if [str(a.GetTargetPrimPath()) for a in arcs] != [class_prim]:
        return False
    # the same matrix up to the round trip through the layer's text (17 significant digits: exact)
    ours = np.asarray(placement.transform, dtype=np.float64).T
    theirs = np.array(UsdGeom.Xformable(prim).GetLocalTransformation())
    return np.allclose(theirs, ours, rtol=0, atol=1e-12 * max(1.0, float(np.abs(ours).max())))


def _hide_field(asset: UsdVol.OpenVDBAsset) -> None:
    """Field prims are Xformable, so DCCs import each as an object (six stray Empties in Blender 5.0).

    Purpose ``guide`` keeps them out of a default import and out of renders; the
    volume still reaches them through its ``field:`` relationships (Blender
    reads the grids, measured), which is how every consumer finds fields.
    """
    asset.CreatePurposeAttr(UsdGeom.Tokens.guide)


def stage_metadata(stage_path: Path) -> dict:
    """upAxis, metersPerUnit and defaultPrim of the input's root layer (copied into outputs)."""
    layer = Sdf.Layer.FindOrOpen(str(stage_path))
    meta = {}
    for key in ("upAxis", "metersPerUnit", "defaultPrim"):
        if layer is not None and layer.pseudoRoot.HasInfo(key):
            meta[key] = layer.pseudoRoot.GetInfo(key)
    return meta


def relocate_and_seal(staging: Path, final_dir: Path, names: list[str]) -> list[str]:
    """Make layers written in ``staging`` right for ``final_dir``, where they will be moved; their names, bottom layer first.

    A relative asset path that leads out of ``staging`` (the input a bake's
    first layer sublayers) is rewritten relative to ``final_dir``; paths to
    files beside it stay. Then each layer records the files below it again
    (``integrity.seal``), in sublayer order, so every record holds the final
    content of the layer it names.
    """
    from pxr import UsdUtils

    staging = Path(staging).resolve()
    layers = {}
    for n in names:
        # a private copy of what is on disk: editing the registry's layer would make the stages this process
        # still holds over it recompose (and miss the input, whose path is now right for final_dir only)
        layers[n] = Sdf.Layer.OpenAsAnonymous(str(staging / n))

    def rewrite(asset: str) -> str:
        if not asset.startswith(("./", "../")):
            return asset  # absolute, a URI or a search path: the same from anywhere
        target = Path(os.path.normpath(staging / asset))
        return asset if target.parent == staging else _relative(target, final_dir)

    order: list[str] = []

    def visit(n: str, trail: tuple[str, ...] = ()) -> None:
        if n in order or n in trail:
            return
        for sub in layers[n].subLayerPaths:
            dep = os.path.normpath(sub)
            if dep in layers:
                visit(dep, trail + (n,))
        order.append(n)

    for n in sorted(layers):
        visit(n)
    commit = new_commit_id()
    for n in order:
        layer = layers[n]
        UsdUtils.ModifyAssetPaths(layer, rewrite)
        seal(layer, locator(staging, final_dir), commit)
        if not layer.Export(str(staging / n)):
            raise OutputError(f"@{final_dir / n}@: cannot be written.")
    return order
