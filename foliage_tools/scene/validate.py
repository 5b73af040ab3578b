"""``foliage validate``: USD's own validators plus the foliage rules.

Each rule is a small function with a one-line description that *collects*
:class:`Finding` objects instead of raising (after usdchecker). Messages use
USD's notation: prim paths in ``<...>``, asset paths in ``@...@``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from foliage_tools.errors import InputError
from foliage_tools.geometry.leaves import DEGENERATE_AREA, triangle_area_normals, triangulate
from foliage_tools.scene import bakeable, usd_diagnostics
from foliage_tools.scene.integrity import USD_SUFFIXES, check_layer, pending_for, record_of
from foliage_tools.geometry.sun import choose_sun, direction_from_angles
from foliage_tools.scene.read import SIDEWAYS, _is_skipped, classify_leaf, open_stage, read_light, read_stage
from foliage_tools.scene.schemas import register

register()

from pxr import Tf, Usd, UsdGeom, UsdLux, UsdValidation  # noqa: E402

ERROR = "error"
WARNING = "warning"
#: A note that fails nothing, even with --strict: what a user may want to know of a result that is as it should be.
INFO = "info"

#: The built-in UsdValidation validators that apply to tree assets (physics,
#: skeleton and usdz-packaging validators do not).
USD_VALIDATORS = (
    "usdValidation:CompositionErrorTest",
    "usdValidation:StageMetadataChecker",
    "usdValidation:AttributeTypeMismatch",
    "usdGeomValidators:StageMetadataChecker",
    "usdGeomValidators:EncapsulationChecker",
    "usdGeomValidators:SubsetFamilies",
    "usdGeomValidators:SubsetParentIsImageable",
    "usdShadeValidators:MaterialBindingApiAppliedValidator",
    "usdShadeValidators:MaterialBindingRelationships",
    "usdShadeValidators:EncapsulationRulesValidator",
    "usdShadeValidators:ShaderSdrCompliance",
    "usdLuxValidators:EncapsulationRulesValidator",
    "usdUtilsValidators:MissingReferenceValidator",
)


@dataclass(frozen=True)
class Finding:
    severity: str
    rule: str
    message: str
    prim: str = ""

    def as_dict(self) -> dict:
        return asdict(self)


Rule = Callable[[Usd.Stage, str], Iterator[Finding]]
RULES: list[tuple[str, str, Rule]] = []


def rule(name: str, doc: str):
    def deco(fn: Rule) -> Rule:
        RULES.append((name, doc, fn))
        return fn

    return deco


def _meshes(stage: Usd.Stage) -> Iterator[Usd.Prim]:
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()):
        if prim.IsA(UsdGeom.Mesh):
            yield prim


def _mesh_arrays(prim: Usd.Prim) -> tuple:
    """A mesh's points, faceVertexCounts and faceVertexIndices as authored (None when not, or of a type USD does not
    know: the attribute-types rule's)."""
    return bakeable.mesh_arrays(prim)


def _is_empty(prim: Usd.Prim) -> bool:
    """A mesh the readers skip for lack of points or faces (:func:`bakeable.mesh_lacks`)."""
    return bakeable.mesh_lacks(*_mesh_arrays(prim)) is not None


@rule("leaf-meshes-found", "The stage holds at least one leaf mesh (DESIGN.md leaf rule) that the bakes read: visible, "
      "with points and faces.")
def _leaf_meshes(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    meshes = list(_meshes(stage))
    if not meshes:
        yield Finding(ERROR, "leaf-meshes-found", f"@{path}@ has no meshes; foliage bakes need leaf geometry.")
    elif not any(classify_leaf(m)[0] for m in meshes):
        yield Finding(
            ERROR,
            "leaf-meshes-found",
            f"@{path}@: none of its {len(meshes)} meshes is a leaf mesh. Apply FoliageLeafAPI, set "
            "primvars:foliage:isLeaf = true, or name the mesh or its material leaf/leaves/foliage/needle.",
        )
    else:
        read = {p.GetPath() for p in _bakeable_prims(stage) if p.IsA(UsdGeom.Mesh)}
        leaves = [m for m in meshes if m.GetPath() in read and classify_leaf(m)[0]]  # as scene.read sees the stage
        if not leaves:
            hidden = ", ".join(f"<{m.GetPath()}>" for m in meshes if classify_leaf(m)[0])
            yield Finding(
                ERROR,
                "leaf-meshes-found",
                f"@{path}@: its leaf meshes ({hidden}) are all invisible or of guide/proxy purpose, which bakes leave "
                "out, so no bake finds a leaf. Make them visible with the default (or render) purpose.",
            )
        elif all(_is_empty(m) for m in leaves):
            empty = ", ".join(f"<{m.GetPath()}>" for m in leaves)
            yield Finding(
                ERROR,
                "leaf-meshes-found",
                f"@{path}@: its leaf meshes ({empty}) all lack points or faces, which bakes skip, so no bake finds a "
                "leaf. Give them their geometry (the empty-meshes warnings say what each lacks).",
            )


@rule("finite-geometry", "Mesh points are finite and faces index valid points.")
def _finite(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    for prim in _meshes(stage):
        pts, counts, idx = _mesh_arrays(prim)
        if bakeable.mesh_lacks(pts, counts, idx) is not None:
            continue  # the readers skip it: the empty-meshes rule's warning
        p = np.asarray(pts, dtype=np.float64)
        nonfinite = bakeable.nonfinite_points(str(prim.GetPath()), p)
        if nonfinite:  # the reader's refusal, word for word
            yield Finding(ERROR, "finite-geometry", f"@{path}@: {nonfinite}", str(prim.GetPath()))
        counts, idx = np.asarray(counts, dtype=np.int64), np.asarray(idx, dtype=np.int64)
        broken = bakeable.topology_problem(str(prim.GetPath()), p.shape[0], counts, idx)
        if broken:
            yield Finding(ERROR, "finite-geometry", f"@{path}@: mesh {broken}", str(prim.GetPath()))  # as the reader


@rule("stage-units", "metersPerUnit is a finite positive float32 number (bakes record the stage's units) and upAxis is Y or Z.")
def _stage_units(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    for problem in bakeable.stage_problems(stage, path):
        yield Finding(ERROR, problem.rule, problem.message, problem.prim)


def _bakeable_prims(stage: Usd.Stage) -> Iterator[Usd.Prim]:
    """Prims a bake reads (as scene.read does: invisible, guide and proxy subtrees left out), through instances."""
    it = iter(Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()))
    for prim in it:
        if _is_skipped(prim, own_only=True):  # (pruned below a skipped prim)
            it.PruneChildren()
            continue
        yield prim


@rule("transforms", "Meshes, point-instanced instances and distant lights have affine world transforms USD can compute that neither collapse (scale 0) nor overflow.")
def _transforms(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    xf = UsdGeom.XformCache()
    seen = set()
    for prim in _bakeable_prims(stage):
        problem = None
        try:
            if prim.IsA(UsdGeom.Mesh):
                problem = bakeable.transform_problem(prim, np.array(xf.GetLocalToWorldTransform(prim)).T, path)
            elif prim.IsA(UsdLux.DistantLight):
                problem = bakeable.light_problem(prim, np.array(xf.GetLocalToWorldTransform(prim)).T, path)
            elif prim.IsA(UsdGeom.PointInstancer):
                # one whose lists do not line up is the instancers rule's (USD warns computing its transforms)
                problem = None if bakeable.instancer_index_problem(prim, path) else bakeable.instancer_transform_problem(
                    prim, np.array(xf.GetLocalToWorldTransform(prim)).T, path)
        except Tf.ErrorException:  # an op USD cannot compute, here or above: the prim whose own op it is
            xf = UsdGeom.XformCache()
            p = prim
            while p and not p.IsPseudoRoot() and problem is None:
                problem = bakeable.local_transform_problem(p, path)
                p = p.GetParent()
        if problem is not None and problem.message not in seen:  # once per culprit, not per mesh under it
            seen.add(problem.message)
            yield Finding(ERROR, problem.rule, problem.message, problem.prim)


@rule("attribute-types", "Attributes the bakes read (mesh points and faces, instancer lists, light values) have types USD knows.")
def _attribute_types(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    for prim in _bakeable_prims(stage):
        problem = bakeable.attribute_type_problem(prim, path)
        if problem is not None:
            yield Finding(ERROR, problem.rule, problem.message, problem.prim)


@rule("lights", "DistantLights and DomeLights have finite, non-negative intensity and colour.")
def _lights(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    for prim in _bakeable_prims(stage):
        if (prim.IsA(UsdLux.DistantLight) or prim.IsA(UsdLux.DomeLight)) and not bakeable.attribute_type_problem(prim, path):
            problem = bakeable.light_value_problem(prim, path)
            if problem is not None:
                yield Finding(ERROR, problem.rule, problem.message, problem.prim)


@rule("sun", "The sun the bakes take from the stage (its first DistantLight) is above the horizon.")
def _sun(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    if any(True for _ in bakeable.stage_problems(stage, path)):
        return  # an up axis the bakes do not take has no horizon: the stage-units rule's
    xf = UsdGeom.XformCache()
    for prim in _bakeable_prims(stage):
        if not prim.IsA(UsdLux.DistantLight):
            continue
        try:
            light = read_light(prim, xf.GetLocalToWorldTransform(prim), path)
        except (InputError, Tf.ErrorException):
            return  # a sun pointing nowhere or of bad values: the transforms and lights rules'
        up = str(UsdGeom.GetStageUpAxis(stage))
        sun = choose_sun([light], up, None, [])
        problem = bakeable.sun_horizon_problem(path, sun, direction_from_angles(0.0, 90.0, up))
        if problem is not None:
            yield Finding(ERROR, problem.rule, problem.message, problem.prim)
        return  # the first DistantLight is the sun (geometry.sun.choose_sun)


@rule("instancers", "Every point instancer's prototypes exist and each of its protoIndices names one of them.")
def _instancers(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    for prim in _bakeable_prims(stage):
        if prim.IsA(UsdGeom.PointInstancer):
            problem = bakeable.instancer_index_problem(prim, path)
            if problem is not None:
                yield Finding(ERROR, problem.rule, problem.message, problem.prim)


@rule("nested-instancing", "No instancing inside a point instancer's prototype (warning: the bakes read one level and leave it out).")
def _nested_instancing(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    for prim in _bakeable_prims(stage):
        if not prim.IsA(UsdGeom.PointInstancer):
            continue
        for target in UsdGeom.PointInstancer(prim).GetPrototypesRel().GetTargets():
            root = stage.GetPrimAtPath(target)
            if not root:
                continue  # the instancers rule reports it
            # as scene.read reads a prototype: an instanceable root is read through its USD prototype (still one
            # level, so seen through here as instance proxies); a point instancer, at the root or below, and an
            # instance below the root are a second level
            it = iter(Usd.PrimRange(root, Usd.TraverseInstanceProxies()))
            for inner in it:
                if _is_skipped(inner, own_only=inner != root):
                    it.PruneChildren()
                elif inner.IsA(UsdGeom.PointInstancer) or (inner.IsInstance() and inner != root):
                    if inner == root:
                        what = (f"prototype <{root.GetPath()}> of point instancer <{prim.GetPath()}> is itself a point "
                                "instancer; the bakes read one level of instancing and leave its instances out: "
                                + bakeable.NESTED_INSTANCING_FIX)
                    else:
                        what = (f"<{inner.GetPath()}> instances geometry inside prototype <{root.GetPath()}> of point "
                                f"instancer <{prim.GetPath()}>; the bakes read one level of instancing and leave it out: "
                                + bakeable.NESTED_INSTANCING_FIX)
                    yield Finding(WARNING, "nested-instancing", f"@{path}@: {what}", str(inner.GetPath()))
                    it.PruneChildren()


@rule("empty-meshes", "Every mesh has points and faces (warning: the bakes skip one without).")
def _empty_meshes(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    for prim in _bakeable_prims(stage):
        if not prim.IsA(UsdGeom.Mesh):
            continue
        lacks = bakeable.mesh_lacks(*_mesh_arrays(prim))
        if lacks is not None:
            what = "leaf " if classify_leaf(prim)[0] else ""
            yield Finding(WARNING, "empty-meshes", f"@{path}@: {what}mesh <{prim.GetPath()}> has {lacks}; the bakes "
                          "skip it. Give it its geometry, or remove it.", str(prim.GetPath()))


@rule("leaf-area", "Every leaf mesh has some nonzero-area triangle (a mesh of only degenerate ones holds no leaf).")
def _leaf_area(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    for prim in _bakeable_prims(stage):
        if not prim.IsA(UsdGeom.Mesh) or not classify_leaf(prim)[0]:
            continue
        pts, counts, idx = _mesh_arrays(prim)
        if pts is None or counts is None or idx is None or len(pts) == 0:
            continue
        p = np.asarray(pts, dtype=np.float64)
        counts, idx = np.asarray(counts, dtype=np.int64), np.asarray(idx, dtype=np.int64)
        if not np.isfinite(p).all() or bakeable.topology_problem("", p.shape[0], counts, idx):
            continue  # reported by finite-geometry
        problem = bakeable.leaf_area_problem(str(prim.GetPath()), p, triangulate(counts, idx)[0], path)
        if problem is not None:
            yield Finding(ERROR, problem.rule, problem.message, problem.prim)


@rule("degenerate-geometry", "No zero-area triangles (they carry no leaf area and break normals).")
def _degenerate(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    for prim in _meshes(stage):
        pts, counts, idx = _mesh_arrays(prim)
        if pts is None or counts is None or idx is None or len(pts) == 0:
            continue
        p = np.asarray(pts, dtype=np.float64)
        counts = np.asarray(counts, dtype=np.int64)
        idx = np.asarray(idx, dtype=np.int64)
        if not np.isfinite(p).all() or bakeable.topology_problem("", p.shape[0], counts, idx):
            continue  # reported by finite-geometry
        tris, _ = triangulate(counts, idx)
        area, _ = triangle_area_normals(p, tris)
        diag = float(np.linalg.norm(p.max(axis=0) - p.min(axis=0))) or 1.0
        n = int(np.count_nonzero(area <= DEGENERATE_AREA * diag * diag))
        if n:
            yield Finding(WARNING, "degenerate-geometry", f"@{path}@: <{prim.GetPath()}> has {n} degenerate (zero-area) triangle(s); bakes ignore them.", str(prim.GetPath()))


def _expected_length(prim: Usd.Prim, interpolation: str) -> int | None:
    pts, counts, idx = _mesh_arrays(prim)
    if interpolation == UsdGeom.Tokens.constant:
        return 1
    if interpolation == UsdGeom.Tokens.uniform:
        return len(counts) if counts is not None else None
    if interpolation in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        return len(pts) if pts is not None else None
    if interpolation == UsdGeom.Tokens.faceVarying:
        return len(idx) if idx is not None else None
    return None


@rule("primvar-lengths", "Primvar lengths match their interpolation (times elementSize).")
def _primvar_lengths(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    for prim in _meshes(stage):
        if _is_empty(prim):
            continue  # the readers skip it (the empty-meshes rule's warning), and its primvars with it
        for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvarsWithAuthoredValues():
            value = pv.Get()
            if value is None or not hasattr(value, "__len__") or isinstance(value, str):
                continue
            expected = _expected_length(prim, pv.GetInterpolation())
            if expected is None:
                continue
            es = max(pv.GetElementSize(), 1)
            if pv.IsIndexed():
                n = len(pv.GetIndices())
                indices = np.asarray(pv.GetIndices())
                if indices.size and (indices.min() < 0 or indices.max() >= len(value)):
                    yield Finding(ERROR, "primvar-lengths", f"@{path}@: <{prim.GetPath()}>.{pv.GetName()}: indices reach outside its {len(value)} values; re-export the primvar or remove it.", str(prim.GetPath()))
            else:
                n = len(value)
            if n != expected * es:
                yield Finding(
                    ERROR,
                    "primvar-lengths",
                    f"@{path}@: <{prim.GetPath()}>.{pv.GetName()}: {n} values for {pv.GetInterpolation()} interpolation "
                    f"(elementSize {es}) but the mesh needs {expected * es}; re-export the primvar or remove it.",
                    str(prim.GetPath()),
                )


@rule("volume-grids", "Referenced .vdb files are regular files OpenVDB reads, holding the named grids with finite values.")
def _volume_grids(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    for problem in bakeable.volume_problems(stage, path):  # what every bake refuses, in its words
        yield Finding(ERROR, problem.rule, problem.message, problem.prim)


@rule("bake-files-match", "Each bake layer's grid files and upstream layers are the ones it was written with (content hashes in its customLayerData).")
def _bake_files_match(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    layers = [Path(layer.realPath) for layer in stage.GetUsedLayers() if layer.realPath]
    for layer in sorted({p for p in layers if p.suffix in USD_SUFFIXES}):
        try:
            messages = check_layer(layer)
        except InputError as exc:  # a record foliage did not write: what every bake refuses, in its words
            messages = [str(exc)]
        for message in messages:
            yield Finding(ERROR, "bake-files-match", message)
    waiting: dict[Path, list[str]] = {}
    for layer in sorted(set(layers)):
        staging = pending_for(layer) if record_of(layer) is not None else None
        if staging is not None:
            waiting.setdefault(staging, []).append(layer.name)
    for staging, names in waiting.items():
        yield Finding(
            WARNING, "bake-files-match",
            f"@{staging}@ holds newer versions of {', '.join(names)} from a run that was killed while moving them into "
            "place; the next foliage run writing the same output finishes the move (or remove that directory).",
        )


@rule("portable-folder", "A bake layer's sublayer path stays inside its folder (info: else the folder moves only with its input; bake --portable).")
def _portable_folder(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    from foliage_tools.scene.portable import escaping_sublayers

    for layer in stage.GetUsedLayers():
        if not layer.realPath or record_of(Path(layer.realPath)) is None:
            continue  # only foliage's own layers: an asset's layout is its author's business
        for sub in escaping_sublayers(layer):
            yield Finding(  # a default bake is meant to sit beside its input: a note, not a failure of --strict
                INFO, "portable-folder",
                f"@{layer.realPath}@ sublayers @{sub}@, outside its folder: moved without it, the folder opens as an empty "
                "scene. Move both together, or bake with `foliage bake --portable` (a flattened copy of the input in the folder).",
            )


@rule("leaf-optics-attributes", "foliage:leaf:reflectance / transmittance are reserved and not read yet (the bake's --leaf-optics applies).")
def _leaf_optics_attributes(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    for prim in _meshes(stage):
        authored = [n for n in ("foliage:leaf:reflectance", "foliage:leaf:transmittance")
                    if prim.GetAttribute(n) and prim.GetAttribute(n).HasAuthoredValue()]
        if authored:
            yield Finding(
                WARNING, "leaf-optics-attributes",
                f"@{path}@: <{prim.GetPath()}> authors {' and '.join(authored)}, which foliage-tools does not read yet: the bakes use "
                "--leaf-optics for every leaf. Pass its values with --leaf-optics rR,rG,rB,tR,tG,tB.",
                str(prim.GetPath()),
            )


def _usd_findings(stage: Usd.Stage, path: str) -> Iterator[Finding]:
    reg = UsdValidation.ValidationRegistry()
    names = [n for n in USD_VALIDATORS if reg.HasValidator(n)]
    ctx = UsdValidation.ValidationContext(reg.GetOrLoadValidatorsByName(names))
    found = []
    with usd_diagnostics.captured():  # what USD warns validating (an unresolvable dependency) its findings say
        errors = ctx.Validate(stage)
    for err in errors:
        if err.HasNoError():
            continue
        sites = [str(s.GetPrim().GetPath()) for s in err.GetSites() if s.IsPrim()]
        severity = ERROR if err.GetType() == UsdValidation.ValidationErrorType.Error else WARNING
        validator = err.GetValidator()
        rule_name = validator.GetMetadata().name if validator else err.GetName()
        found.append(Finding(severity, rule_name, usd_diagnostics.relative_paths(err.GetMessage(), path),
                             sites[0] if sites else ""))
    # USD runs its validators in parallel, so their errors interleave in any order: grouped in USD_VALIDATORS'
    # order (a stable sort keeps each validator's own order), the same stage always reads the same (a CI log's
    # diff, the corpus baselines)
    order = {name: k for k, name in enumerate(USD_VALIDATORS)}
    yield from sorted(found, key=lambda f: (order.get(f.rule, len(order)), f.rule))


def validate(path: str | Path) -> list[Finding]:
    """All findings for the stage at ``path`` (raises :class:`InputError` if it cannot be opened).

    When the rules find no error, the stage is read as every bake reads it (``scene.read.read_stage``): its
    refusal is a finding too, so what a bake refuses, validate fails, in the bake's words.
    """
    stage = open_stage(path)
    findings = _guarded("usd", lambda: list(_usd_findings(stage, str(path))), stage, str(path))
    for name, _, fn in RULES:
        findings.extend(_guarded(name, partial(_run_rule, fn, stage, str(path)), stage, str(path)))
    if not any(f.severity == ERROR for f in findings):
        try:
            with usd_diagnostics.captured():  # what USD warns reading is the rules' to say
                _, read_warnings = read_stage(stage, str(path))
            findings += [Finding(WARNING, "upright", w) for w in read_warnings if SIDEWAYS in w]
        except InputError as exc:
            findings.append(Finding(ERROR, getattr(exc, "rule", "bakeable"), str(exc), getattr(exc, "prim", "")))
    return findings


def _run_rule(fn: Rule, stage: Usd.Stage, path: str) -> list[Finding]:
    return list(fn(stage, path))


def _guarded(name: str, run: Callable[[], list[Finding]], stage: Usd.Stage, path: str) -> list[Finding]:
    """A rule's findings; when USD raises computing them (a value it cannot compute), the prims whose own values do
    it (``bakeable.usd_error_problems``), else what USD said, as findings of that rule."""
    try:
        return run()
    except Tf.ErrorException as exc:
        found = [Finding(ERROR, p.rule, p.message, p.prim) for p in bakeable.usd_error_problems(stage, path)]
        return found or [Finding(ERROR, name, f"@{path}@: USD cannot compute this rule's check "
                                 f"({usd_diagnostics.open_failure(exc, path)}); fix or re-export the asset.")]


#: Findings of the scene reader's own (``validate`` reads the stage as the bakes do once its rules find no error).
READER_RULES = (
    ("upright", "Each tree stands along the stage's upAxis, by its trunk (warning: else the bakes light it from the side)."),
)


def rule_docs() -> list[tuple[str, str]]:
    return ([(name, doc) for name, doc, _ in RULES] + list(READER_RULES)
            + [(n, "USD built-in validator") for n in USD_VALIDATORS])
