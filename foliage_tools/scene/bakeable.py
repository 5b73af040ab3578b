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
from typing import Iterator

import numpy as np
from pxr import Usd, UsdGeom

from foliage_tools.geometry.leaves import DEGENERATE_AREA, triangle_area_normals
from foliage_tools.scene.usd_diagnostics import relative_paths

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


def stage_problems(stage: Usd.Stage, path: str) -> Iterator[Problem]:
    """Stage metadata a bake relies on: metersPerUnit (DESIGN.md section 3, units)."""
    mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
    if not (math.isfinite(mpu) and mpu > 0.0):
        yield Problem(
            "stage-units",
            f"@{path}@: metersPerUnit is {mpu:g}; lengths need a finite, positive unit. Set it in the root layer "
            "(e.g. metersPerUnit = 1 for metres, 0.01 for centimetres).",
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


def _bad_scale(s: np.ndarray | None) -> bool:
    return s is None or float(s.min()) < MIN_SCALE or float(s.max()) > MAX_SCALE


def _describe(s: np.ndarray | None) -> str:
    if s is None:
        return "a transform with NaN or infinite entries"
    if float(s.min()) < MIN_SCALE:
        return f"a transform that scales by {float(s.min()):.3g} (it flattens its geometry; the matrix has no inverse)"
    return f"a transform that scales by {float(s.max()):.3g} (coordinates and areas would overflow)"


def transform_problem(prim: Usd.Prim, world: np.ndarray, path: str) -> Problem | None:
    """A prim whose world transform (4x4) collapses or overflows, naming the ancestor whose own transform does it
    (the prim itself when only their product does)."""
    s = _scales(world)
    if not _bad_scale(s):
        return None
    culprit, cs = prim, s
    p = prim
    while p and not p.IsPseudoRoot():
        xf = UsdGeom.Xformable(p)
        if xf:
            local = _scales(np.array(xf.GetLocalTransformation(Usd.TimeCode.Default()), dtype=np.float64))
            if _bad_scale(local):
                culprit, cs = p, local
                break
        p = p.GetParent()
    # the message names the prim whose own transform does it, so every mesh below it reports the same line
    return Problem(
        "transforms",
        f"@{path}@: <{culprit.GetPath()}> has {_describe(cs)}, so a bake cannot place the geometry at or under it. Give "
        f"<{culprit.GetPath()}> a finite scale between {MIN_SCALE:g} and {MAX_SCALE:g}, or make it invisible to leave it out.",
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
    if math.isfinite(n) and MIN_SCALE <= n <= MAX_SCALE:
        return None
    return Problem(
        "transforms",
        f"@{path}@: DistantLight <{prim.GetPath()}> has {_describe(_scales(m))}, so it points in no direction and "
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
