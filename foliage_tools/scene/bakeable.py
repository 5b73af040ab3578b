"""What a bake cannot handle: the checks ``foliage validate`` reports as errors and the scene reader refuses (exit 2).

One function per kind of problem, each returning :class:`Problem` objects
(or None) with the message both sides print, so ``validate`` and every
command that reads a scene say the same thing about the same prim.
Messages use USD's notation: prim paths in ``<...>``, asset paths in ``@...@``.
"""

from __future__ import annotations

import re

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
from pxr import Sdf, Tf, Usd, UsdGeom, UsdLux, UsdVol

from foliage_tools.errors import InputError
from foliage_tools.geometry.leaves import DEGENERATE_AREA, triangle_area_normals
from foliage_tools.scene.usd_diagnostics import open_failure, relative_paths

#: Scales a transform may apply (singular values of its linear part). Below, the
#: geometry collapses (its inverse, the prototype frame and the sun seen from it do
#: not exist); above, areas (length squared) and voxel counts overflow float64.
MIN_SCALE = 1e-12
MAX_SCALE = 1e12


@dataclass(frozen=True)
class Problem:
    rule: str
    message: str
    prim: str = ""


#: The range of metersPerUnit a bake takes: the normal float32 numbers. Every bake records the unit in its layer as
#: a ``float`` (``foliage:metersPerUnit``, FoliageLightingAPI) and in its grids' float metadata, so a value above
#: float32's largest (3.4e38) is written as infinity (1e300 was), and one below its smallest normal (1.2e-38) loses
#: its precision or becomes 0. Lengths themselves stay in stage units, so no other arithmetic of the bakes uses it.
MIN_METERS_PER_UNIT = float(np.finfo(np.float32).tiny)
MAX_METERS_PER_UNIT = float(np.finfo(np.float32).max)
#: The up axes USD allows (UsdGeom: upAxis is Y or Z); the sun's azimuth and elevation are defined about them.
UP_AXES = ("Y", "Z")


def stage_problems(stage: Usd.Stage, path: str) -> Iterator[Problem]:
    """Stage metadata a bake relies on: metersPerUnit (DESIGN.md section 3, units) and upAxis."""
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    if not (math.isfinite(mpu) and MIN_METERS_PER_UNIT <= mpu <= MAX_METERS_PER_UNIT):
        why = ("lengths need a finite, positive unit" if not (math.isfinite(mpu) and mpu > 0.0) else
               f"the bakes record it as a 32-bit float, which holds {MIN_METERS_PER_UNIT:.3g} to {MAX_METERS_PER_UNIT:.3g}")
        yield Problem(
            "stage-units",
            f"@{path}@: metersPerUnit is {mpu:g}; {why}. Set it in the root layer "
            "(e.g. metersPerUnit = 1 for metres, 0.01 for centimetres).",
        )
    up = str(UsdGeom.GetStageUpAxis(stage))
    if up not in UP_AXES:
        yield Problem(
            "stage-units",
            f"@{path}@: upAxis is {up!r}; USD allows only \"Y\" or \"Z\", the axes the sun's elevation is measured "
            "from. Set upAxis = \"Y\" or \"Z\" in the root layer (and rotate the asset if it stands on X).",
        )


def composition_problems(stage: Usd.Stage, path: str) -> Iterator[Problem]:
    """Sublayers or references USD could not load, and sublayer cycles: the bake would see part of the asset."""
    for err in stage.GetCompositionErrors():
        # the missing file as the asset names it; USD's "; skipping." would contradict the refusal that follows
        text = relative_paths(re.sub(r";\s*skipping\.?\s*$", "", str(err).strip()).rstrip(".;"), path)
        yield Problem(
            "composition",
            f"@{path}@: {text}. A bake would silently leave that part of the asset out: fix or remove the path in "
            "the layer named, then run `foliage validate` again.",
        )


#: What to do about instancing inside a point instancer's prototype, which the bakes read one level of (the
#: reader's warning and validate's nested-instancing rule say it in these words).
NESTED_INSTANCING_FIX = "place those instances from the outer instancer, or make them plain (non-instanced) prims."


def nonfinite_points(prim_path: str, points: np.ndarray) -> str | None:
    """What is wrong with a mesh whose points (n, 3) are not all finite (the reader refuses it, validate's
    finite-geometry rule reports it, in these words), or None."""
    bad = int(np.count_nonzero(~np.isfinite(points).all(axis=1)))
    if not bad:
        return None
    return (f"mesh <{prim_path}> has {bad} point(s) with NaN or infinite coordinates; fix the asset (e.g. re-export "
            "it) before baking.")


def topology_problem(prim_path: str, n_points: int, counts: np.ndarray, indices: np.ndarray) -> str | None:
    """Why a mesh's faces cannot be triangulated, or None."""
    if counts.size and counts.min() < 3:
        bad = counts[counts < 3]
        return (f"<{prim_path}> has {bad.size} face(s) with fewer than 3 vertices (faceVertexCounts as low as "
                f"{int(bad.min())}); fix the asset's faceVertexCounts.")
    if int(counts.sum()) != indices.shape[0]:
        return (f"<{prim_path}>: faceVertexCounts sum to {int(counts.sum())} but there are {indices.shape[0]} "
                "faceVertexIndices; fix the asset.")
    if indices.size and (indices.min() < 0 or indices.max() >= n_points):
        return f"<{prim_path}>: faceVertexIndices reach outside its {n_points} points; fix the asset."
    return None


def _scales(m: np.ndarray) -> np.ndarray | None:
    """Singular values of a 4x4 (either convention) transform's linear part; None if it is not finite."""
    m = np.asarray(m, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        return None
    with np.errstate(all="ignore"):
        s = np.linalg.svd(m[:3, :3], compute_uv=False)
    return s if np.all(np.isfinite(s)) else None


def _projective(m: np.ndarray) -> bool:
    """A 4x4 transform (column-vector convention) that is not affine: its last row is not (0, 0, 0, 1) (a w = 0 or
    a perspective row, which USD's matrix ops can author and no bake can place geometry with)."""
    m = np.asarray(m, dtype=np.float64)
    return not np.all(np.isfinite(m[3])) or bool(np.max(np.abs(m[3] - (0.0, 0.0, 0.0, 1.0))) > 1e-9)


def _bad_scale(s: np.ndarray | None) -> bool:
    return s is None or float(s.min()) < MIN_SCALE or float(s.max()) > MAX_SCALE


def _describe(s: np.ndarray | None, projective: bool = False) -> str:
    if projective:
        return "a projective transform (its matrix's last column is not (0, 0, 0, 1): not a rotation, scale and move)"
    if s is None:
        return "a transform with NaN or infinite entries"
    if float(s.min()) < MIN_SCALE:
        return f"a transform that scales by {float(s.min()):.3g} (it flattens its geometry; the matrix has no inverse)"
    return f"a transform that scales by {float(s.max()):.3g} (coordinates and areas would overflow)"


def transform_problem(prim: Usd.Prim, world: np.ndarray, path: str) -> Problem | None:
    """A prim whose world transform (4x4) collapses or overflows, naming the ancestor whose own transform does it
    (the prim itself when only their product does)."""
    s = _scales(world)
    projective = _projective(world)
    if not _bad_scale(s) and not projective:
        return None
    culprit, cs = prim, s
    p = prim
    while p and not p.IsPseudoRoot():
        xf = UsdGeom.Xformable(p)
        if xf:
            m = np.array(xf.GetLocalTransformation(Usd.TimeCode.Default()), dtype=np.float64).T
            local = _scales(m)
            if _bad_scale(local) or _projective(m):
                culprit, cs, projective = p, local, _projective(m)
                break
        p = p.GetParent()
    # the message names the prim whose own transform does it, so every mesh below it reports the same line
    return Problem(
        "transforms",
        f"@{path}@: <{culprit.GetPath()}> has {_describe(cs, projective)}, so a bake cannot place the geometry at or under "
        f"it. Give <{culprit.GetPath()}> an affine transform with a finite scale between {MIN_SCALE:g} and {MAX_SCALE:g}, "
        "or make it invisible to leave it out.",
        str(culprit.GetPath()),
    )


def mesh_lacks(points, counts, indices) -> str | None:
    """What a mesh lacks, e.g. "2 face(s) but no points (points is empty)", or None when it has points and faces.

    The readers skip a mesh that lacks any of points, faceVertexCounts and faceVertexIndices, whether the
    attribute is unauthored or an empty array: both hold nothing to triangulate.
    """
    arrays = {"points": points, "faceVertexCounts": counts, "faceVertexIndices": indices}
    missing = [name for name, values in arrays.items() if values is None or len(values) == 0]
    if not missing:
        return None
    has = [f"{len(values)} {noun}" for name, values, noun in
           (("points", points, "point(s)"), ("faceVertexCounts", counts, "face(s)")) if name not in missing]
    lacks = [noun for name, noun in (("points", "points"), ("faceVertexCounts", "faces")) if name in missing]
    if "faceVertexIndices" in missing and "faceVertexCounts" not in missing:  # (a mesh without faces has none)
        lacks.append("face vertex indices")
    why = ", ".join(f"{name} is {'not authored' if arrays[name] is None else 'empty'}" for name in missing)
    return f"{' and '.join(has) + ' but ' if has else ''}no {' and no '.join(lacks)} ({why})"


#: Per-instance lists of a PointInstancer that must be as long as protoIndices when authored (USD computes no
#: instance transforms otherwise).
_PER_INSTANCE = ("positions", "orientations", "scales")


def instancer_index_problem(prim: Usd.Prim, path: str) -> Problem | None:
    """A PointInstancer whose prototypes relationship names a missing prim or the instancer itself (or a prim
    above it), whose protoIndices name no prototype, or whose positions, orientations or scales are not one per
    instance (USD then computes no instance transforms at all)."""
    pi = UsdGeom.PointInstancer(prim)
    targets = pi.GetPrototypesRel().GetTargets()
    stage = prim.GetStage()
    missing = [str(t) for t in targets if not stage.GetPrimAtPath(t)]
    if missing:
        return Problem("instancers", f"@{path}@: point instancer <{prim.GetPath()}> names a missing prototype <{missing[0]}>"
                       f"{f' (and {len(missing) - 1} more)' if len(missing) > 1 else ''}. Add the prototype's prim, or "
                       "take it out of the instancer's prototypes relationship.", str(prim.GetPath()))
    selfish = [str(t) for t in targets if prim.GetPath().HasPrefix(t)]
    if selfish:
        return Problem("instancers", f"@{path}@: point instancer <{prim.GetPath()}> names <{selfish[0]}>, itself or a prim "
                       "above it, as a prototype, so it would instance itself. Point its prototypes relationship at "
                       "prims outside it and below the instancer's own prototypes scope.", str(prim.GetPath()))
    authored = pi.GetProtoIndicesAttr().Get(Usd.TimeCode.Default())
    if authored is None:  # no instances: the reader skips the instancer and says so
        return None
    indices = np.asarray(authored, dtype=np.int64)
    for name in _PER_INSTANCE:
        values = prim.GetAttribute(name).Get(Usd.TimeCode.Default())
        if values is not None and len(values) and len(values) != len(indices):
            return Problem("instancers", f"@{path}@: point instancer <{prim.GetPath()}> has {len(values)} {name} for its "
                           f"{len(indices)} protoIndices, so USD places none of its instances. Give it one of each per "
                           "instance.", str(prim.GetPath()))
    bad = np.flatnonzero((indices < 0) | (indices >= len(targets)))
    if bad.size:
        return Problem("instancers", f"@{path}@: point instancer <{prim.GetPath()}> has {bad.size} protoIndices outside "
                       f"0..{len(targets) - 1}, the {len(targets)} prototype(s) it names (first: instance {int(bad[0])}, "
                       f"index {int(indices[bad[0]])}). Fix protoIndices, or add the missing prototypes to its "
                       "prototypes relationship.", str(prim.GetPath()))
    return None


def instancer_problems(prim: Usd.Prim, world: np.ndarray, path: str) -> Iterator[Problem]:
    """A PointInstancer's bad prototypes or lists (:func:`instancer_index_problem`), else its instances whose
    transforms cannot be placed (:func:`instancer_transform_problem`)."""
    problem = instancer_index_problem(prim, path) or instancer_transform_problem(prim, world, path)
    if problem is not None:
        yield problem


def instancer_transform_problem(prim: Usd.Prim, world: np.ndarray, path: str) -> Problem | None:
    """Instances of a PointInstancer (``world`` = the instancer's world transform) whose transforms are not
    finite, collapse or overflow; None too when USD computes none (no instances, or lists that do not line up:
    :func:`instancer_index_problem`)."""
    pi = UsdGeom.PointInstancer(prim)
    t = Usd.TimeCode.Default()
    xforms = pi.ComputeInstanceTransformsAtTime(t, t, UsdGeom.PointInstancer.IncludeProtoXform,
                                                UsdGeom.PointInstancer.IgnoreMask)
    if xforms is None or len(xforms) == 0:
        return None
    mask = pi.ComputeMaskAtTime(t)  # instances deactivated by inactiveIds are not read, so not checked
    m = np.asarray(world, dtype=np.float64) @ np.transpose(np.array(xforms, dtype=np.float64).reshape(-1, 4, 4), (0, 2, 1))
    lin = m[:, :3, :3]
    ok = np.all(np.isfinite(lin.reshape(len(lin), -1)), axis=1)
    s = np.full((len(lin), 3), np.nan)
    with np.errstate(all="ignore"):
        if ok.any():
            s[ok] = np.linalg.svd(lin[ok], compute_uv=False)  # the singular values of every instance at once
    good = np.all(np.isfinite(s), axis=1) & (np.nanmin(np.where(np.isfinite(s), s, np.inf), axis=1) >= MIN_SCALE) \
        & (np.nanmax(np.where(np.isfinite(s), s, -np.inf), axis=1) <= MAX_SCALE)
    active = np.ones(len(lin), bool) if not mask else np.asarray(mask, dtype=bool)
    bad = np.flatnonzero(active & ~good).tolist()
    if not bad:
        return None
    return Problem(
        "transforms",
        f"@{path}@: {len(bad)} instance(s) of point instancer <{prim.GetPath()}> (first: index {bad[0]}) have a "
        f"transform that is not finite, collapses or overflows (scales outside {MIN_SCALE:g} to {MAX_SCALE:g}), so "
        "a bake cannot place them. Fix their positions, scales or orientations (or the instancer's own "
        "transform), or deactivate them (inactiveIds).",
        str(prim.GetPath()),
    )


def light_problem(prim: Usd.Prim, world: np.ndarray, path: str) -> Problem | None:
    """A DistantLight whose transform leaves it no direction (scaled to 0, NaN, overflowing)."""
    m = np.asarray(world, dtype=np.float64)
    with np.errstate(all="ignore"):
        axis = m[:3, 2]
        n = float(np.linalg.norm(axis)) if np.all(np.isfinite(axis)) else float("nan")
    if math.isfinite(n) and MIN_SCALE <= n <= MAX_SCALE and not _projective(m):
        return None
    return Problem(
        "transforms",
        f"@{path}@: DistantLight <{prim.GetPath()}> has {_describe(_scales(m), _projective(m))}, so it points in no direction and "
        "cannot be the sun. Give it a finite, nonzero scale (only its rotation matters), or remove it and pass --sun AZ,EL.",
        str(prim.GetPath()),
    )


def leaf_area_problem(prim_path: str, points: np.ndarray, triangles: np.ndarray, path: str) -> Problem | None:
    """A leaf mesh all of whose triangles have zero area (the same test as ``leaf_components``): it holds no leaf."""
    if triangles.shape[0] == 0:
        return None
    diag = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))) or 1.0
    area, _ = triangle_area_normals(points, triangles)
    if np.any(area > DEGENERATE_AREA * diag * diag):
        return None
    return Problem(
        "leaf-area",
        f"@{path}@: leaf mesh <{prim_path}> has zero area: all its {triangles.shape[0]} triangle(s) are degenerate, so "
        "it holds no leaf to light. Fix its points, or mark it as wood (primvars:foliage:isLeaf = false) or make it invisible.",
        prim_path,
    )


def light_values(prim: Usd.Prim) -> tuple[float, tuple[float, float, float]]:
    """A light's intensity and colour as the bakes read them (UsdLux inputs:intensity, inputs:color)."""
    light = UsdLux.LightAPI(prim)
    intensity = light.GetIntensityAttr().Get()
    color = light.GetColorAttr().Get()
    c = (1.0, 1.0, 1.0) if color is None else tuple(float(x) for x in color)
    return (0.0 if intensity is None else float(intensity)), (c[0], c[1], c[2])


def light_value_problem(prim: Usd.Prim, path: str) -> Problem | None:
    """A DistantLight or DomeLight whose intensity or colour is NaN, infinite or negative: the sun's and sky's light
    would carry it into every leaf (the sky's NaN failed inside a bake)."""
    intensity, color = light_values(prim)
    kind = "DistantLight" if prim.IsA(UsdLux.DistantLight) else "DomeLight"
    bad = []
    if not (math.isfinite(intensity) and intensity >= 0.0):
        bad.append(f"inputs:intensity {intensity:g}")
    if not all(math.isfinite(c) and c >= 0.0 for c in color):
        bad.append(f"inputs:color ({', '.join(f'{c:g}' for c in color)})")
    if not bad:
        return None
    return Problem(
        "lights",
        f"@{path}@: {kind} <{prim.GetPath()}> has {' and '.join(bad)}; light needs finite values >= 0. Fix the light's "
        "values, or remove the light (the bakes then take --sun AZ,EL, or a sun at 45,60).",
        str(prim.GetPath()),
    )


def sun_horizon_problem(path: str, sun, up: np.ndarray) -> Problem | None:
    """The sun a bake would use (a ``geometry.sun.Sun``, from ``choose_sun``) at or below the horizon: every bake
    refuses it, and ``validate`` reports a stage's DistantLight so, in the same words."""
    if float(np.dot(np.asarray(sun.direction, dtype=np.float64), np.asarray(up, dtype=np.float64))) > SUN_MIN_HEIGHT:
        return None
    source = str(sun.source)
    where = ("--sun" if source == "--sun" else "the default sun" if source == "default" else
             f"the DistantLight {source} of @{path}@")
    fix = "give --sun AZ,EL with EL > 0" if source in ("--sun", "default") else \
        "turn the DistantLight above the horizon, or give --sun AZ,EL with EL > 0"
    return Problem(
        "sun",
        f"the sun from {where} is at or below the horizon (elevation {sun.elevation:.4g} degrees); the bakes need a sun "
        f"above it: {fix}.",
        source.strip("<>") if source.startswith("<") else "",
    )


#: The sun's height above the horizon (its unit direction's component along the up axis) below which it counts as
#: at or below it.
SUN_MIN_HEIGHT = 1e-9


def volume_problems(stage: Usd.Stage, path: str) -> Iterator[Problem]:
    """Every OpenVDBAsset field whose ``.vdb`` a bake (or a renderer) cannot read: no filePath, a file that is
    missing or is not a regular file (a directory, a FIFO: never opened, so never blocks), one OpenVDB cannot
    read (garbage, cut short), without the named grid, or a grid of NaN or infinite voxels (``vdb.read_grid``).

    A bake refuses its input for any of these (its output would carry the broken field on, and fail ``validate``)."""
    from foliage_tools.scene.dependencies import file_problem
    from foliage_tools.scene.vdb import read_grid

    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()):
        if not prim.IsA(UsdVol.OpenVDBAsset):
            continue
        asset = UsdVol.OpenVDBAsset(prim)
        ap = asset.GetFilePathAttr().Get()
        name = asset.GetFieldNameAttr().Get()
        at = f"@{path}@: <{prim.GetPath()}>"
        if ap is None or not ap.path:
            yield Problem("volume-grids", f"{at} has no filePath; author the .vdb it reads, or remove the field.",
                          str(prim.GetPath()))
            continue
        resolved = ap.resolvedPath or ""
        problem = file_problem(resolved) if resolved else "does not exist"
        if problem is not None:
            yield Problem("volume-grids", f"{at}: @{ap.path}@ {problem}. Re-run the bake that wrote it, or point the "
                          "field at its .vdb file.", str(prim.GetPath()))
            continue
        try:
            read_grid(Path(resolved), name)  # a file OpenVDB reads, holding that grid, of finite voxels
        except InputError as exc:
            text = str(exc)  # naming the file as USD resolved it, where OpenVDB read it
            if "has no grid named" in text:
                from foliage_tools.scene.vdb import grid_names

                names = grid_names(Path(resolved))
                text = (f"@{ap.path}@ has no grid {name!r} (it has {', '.join(names) or 'none'}); re-run the bake that "
                        "wrote it, or correct the field's fieldName.")
            yield Problem("volume-grids", f"{at}: {text}", str(prim.GetPath()))


def local_transform_problem(prim: Usd.Prim, path: str) -> Problem | None:
    """A prim whose own transform USD cannot compute (an xformOp of a type it does not know, an op whose value does
    not fit its type): USD raises computing the world transform of everything under it."""
    xf = UsdGeom.Xformable(prim)
    if not xf:
        return None
    try:
        xf.GetLocalTransformation(Usd.TimeCode.Default())
    except Tf.ErrorException as exc:
        said = open_failure(Tf.ErrorException(*exc.args[:1]), path) if exc.args else "USD gives no reason"
        return Problem(
            "transforms",
            f"@{path}@: <{prim.GetPath()}> has a transform USD cannot compute ({said}), so a bake "
            f"cannot place the geometry at or under it. Fix <{prim.GetPath()}>'s xformOpOrder and xformOp attributes "
            "(translate, rotateXYZ, scale, orient, transform, ...), or make it invisible to leave it out.",
            str(prim.GetPath()),
        )
    return None


def usd_error_problems(stage: Usd.Stage, path: str) -> Iterator[Problem]:
    """What made USD raise while a stage was read: every prim whose own transform it cannot compute."""
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()):
        problem = local_transform_problem(prim, path)
        if problem is not None:
            yield problem


#: The smallest voxel edge OpenVDB stores a grid with: it refuses a linear transform whose determinant (the voxel
#: edge cubed) is below 3e-15 as "nearly singular", i.e. an edge below 1.44e-5 (measured with pyopenvdb 10), in
#: the stage's units, which the grids are in. Rounded up to 2e-5.
MIN_VOXEL = 2e-5


def grid_scale_problem(prototype: str, bounds: np.ndarray, path: str) -> Problem | None:
    """A prototype whose foliage is so small that even the coarsest grid a bake makes (``RESOLUTION_RANGE``'s
    lowest resolution along its longest edge) has voxels below :data:`MIN_VOXEL` (coordinates scaled by 1e-30, a
    single leaf of area 5e-31): no bake can store its grids."""
    from foliage_tools.params import RESOLUTION_RANGE

    lo, hi = np.asarray(bounds, dtype=np.float64)
    longest = float(np.max(hi - lo))
    coarsest = RESOLUTION_RANGE[0]
    if longest / coarsest >= MIN_VOXEL:
        return None
    return Problem(
        "geometry-scale",
        f"@{path}@: the foliage of <{prototype}> is {longest:.3g} units across, so even a {coarsest}-voxel grid has "
        f"voxels of {longest / coarsest:.3g}, below the {MIN_VOXEL:g} units OpenVDB stores a grid with. Scale the asset "
        f"up (at least {coarsest * MIN_VOXEL:g} units across) and set metersPerUnit to keep its size in metres.",
        prototype,
    )


#: A placed leaf must span at least this many single-precision steps of its world coordinates: the ray scene
#: (Embree) holds the world's triangles in float32, whose step at a distance D from the origin is D * 2**-23, so
#: far from the origin a leaf collapses (an instance at 1e25 had all its points on one float32 value, and its
#: light was baked from that, with exit 0).
LEAF_FLOAT32_STEPS = 10


def placement_precision_problem(instance: str, leaf_size: float, reach: float, path: str) -> Problem | None:
    """An instance placed so far from the origin (``reach``: the largest world coordinate of its leaves' box) that
    single-precision coordinates cannot resolve its leaves (``leaf_size``: a typical leaf's width, world units)."""
    step = reach * 2.0**-23
    if not (leaf_size > 0) or step * LEAF_FLOAT32_STEPS <= leaf_size:
        return None
    return Problem(
        "geometry-scale",
        f"@{path}@: <{instance}> stands {reach:.3g} units from the origin, where the ray tracer's single-precision "
        f"coordinates are {step:.3g} apart, too coarse for its leaves of about {leaf_size:.3g}: move the stand nearer "
        f"the origin (within {leaf_size / LEAF_FLOAT32_STEPS * 2.0**23:.3g} units), e.g. by translating its root prim.",
        instance,
    )


#: The attributes a bake reads, by the schema of the prim holding them: a value of a type USD does not know
#: (``point9f[] points``) reads back as an UnregisteredValue, which has no length, no numbers.
READ_ATTRIBUTES = {
    "Mesh": ("points", "faceVertexCounts", "faceVertexIndices", "primvars:foliage:isLeaf"),
    "PointInstancer": ("protoIndices", "positions", "orientations", "scales", "ids", "invisibleIds"),
    "DistantLight": ("inputs:intensity", "inputs:color"),
    "DomeLight": ("inputs:intensity", "inputs:color"),
}


def attribute_type_problem(prim: Usd.Prim, path: str) -> Problem | None:
    """An attribute a bake reads on ``prim`` authored with a type USD does not know, so it has no value to read."""
    for name in READ_ATTRIBUTES.get(str(prim.GetTypeName()), ()):
        attr = prim.GetAttribute(name)
        if not attr or not attr.HasAuthoredValue():
            continue
        if isinstance(attr.Get(Usd.TimeCode.Default()), Sdf.UnregisteredValue):
            stack = attr.GetPropertyStack(Usd.TimeCode.Default())
            authored = str(stack[0].typeName) if stack else "?"
            definition = prim.GetPrimDefinition().GetAttributeDefinition(name)
            expected = f" ({prim.GetTypeName()} makes it {definition.GetTypeName()})" if definition else ""
            return Problem(
                "attribute-types",
                f"@{path}@: <{prim.GetPath()}>.{name} is authored as {authored}, a type USD does not know, so it has no "
                f"value a bake can read{expected}. Author it with its schema's type, or remove it.",
                str(prim.GetPath()),
            )
    if prim.IsA(UsdGeom.Mesh):
        return leaf_flag_problem(prim, path)
    return None


LEAF_FLAG = "primvars:foliage:isLeaf"


def leaf_flag_problem(prim: Usd.Prim, path: str) -> Problem | None:
    """A ``primvars:foliage:isLeaf`` authored as anything but a bool (or a non-empty bool[]): its value says nothing a
    bake could take for leaf or wood (a string "no" is no false)."""
    attr = prim.GetAttribute(LEAF_FLAG)
    if not attr or not attr.HasAuthoredValue():
        return None
    value = attr.Get(Usd.TimeCode.Default())
    if value is None or isinstance(value, Sdf.UnregisteredValue):
        return None  # blocked, or a type USD does not know (attribute_type_problem)
    type_name = attr.GetTypeName()
    if type_name == Sdf.ValueTypeNames.Bool or (type_name == Sdf.ValueTypeNames.BoolArray and len(value) > 0):
        return None
    what = "an empty bool[]" if type_name == Sdf.ValueTypeNames.BoolArray else f"{type_name} {value!r}"
    return Problem(
        "attribute-types",
        f"@{path}@: <{prim.GetPath()}>.{LEAF_FLAG} is {what}, not true or false, so it does not say whether the mesh is "
        f"a leaf. Author `bool {LEAF_FLAG} = true` (or `= false`), or remove it.",
        str(prim.GetPath()),
    )


def mesh_arrays(prim: Usd.Prim) -> tuple:
    """A mesh's points, faceVertexCounts and faceVertexIndices as authored; None for one not authored or of a type
    USD does not know (:func:`attribute_type_problem` reports those)."""
    mesh = UsdGeom.Mesh(prim)
    values = (mesh.GetPointsAttr().Get(), mesh.GetFaceVertexCountsAttr().Get(), mesh.GetFaceVertexIndicesAttr().Get())
    return tuple(None if isinstance(v, Sdf.UnregisteredValue) else v for v in values)
