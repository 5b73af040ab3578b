#!/usr/bin/env python3
"""Seeded procedural trees written as USD: the example assets of foliage-tools.

A tree is a trunk with three levels of branches (one ``Mesh`` of tapered,
capped tubes, ``/Tree/Wood``) and a crown of square leaf cards (one ``Mesh``,
``/Tree/Leaves``), each card with its own four vertices, centred uniformly at
random inside the crown volume and facing a uniformly random direction. The
stage is Z-up, in metres, with a sun (``UsdLux.DistantLight``) and a sky
(``UsdLux.DomeLight``) under ``/Lights``.

Library use (pure numpy, then one writer)::

    geometry = build_tree(leaves=1500, leaf_size=0.1, crown="ellipsoid",
                          height=4.0, crown_radius=1.2, seed=1)
    write_tree("tree.usda", geometry)

Command line: ``python examples/make_tree.py --help``. The same arguments give
a byte-identical file.

Crown layout (``height`` H, ``crown_radius`` R, crown base zb = 0.35 H):

- ``ellipsoid``: centre (0, 0, (zb + H) / 2), semi-axes (R, R, (H - zb) / 2).
- ``cone``: base disc of radius R at z = zb, apex at (0, 0, H).
- ``lobes``: a central ellipsoid spanning zb..H plus 4 side ellipsoids around
  it, all inside the cylinder of radius R between zb and H. Their centres and
  semi-axes are in :attr:`TreeGeometry.crown`.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

CROWNS = ("ellipsoid", "cone", "lobes")
FORMATS = ("usda", "usdc")

#: Height of the crown's bottom as a fraction of the tree height.
CROWN_BASE_FRACTION = 0.35
#: Side lobes of the ``lobes`` crown (besides the central one).
SIDE_LOBES = 4
#: Sides of every branch tube.
TUBE_SIDES = 8
#: Branches per parent: level 1 from the trunk, then per level-1 branch, per level-2 branch.
BRANCHING = (8, 3, 2)

#: Sun direction (DESIGN.md default: azimuth counter-clockwise from +X toward +Y, elevation above the horizon).
SUN_AZIMUTH_DEG = 45.0
SUN_ELEVATION_DEG = 60.0
#: Angular diameter of the sun as seen from the earth, degrees.
SUN_ANGLE_DEG = 0.53
SKY_INTENSITY = 0.3
SKY_COLOR = (0.55, 0.7, 1.0)

BARK_COLOR = (0.35, 0.25, 0.15)
LEAF_COLOR = (0.2, 0.45, 0.1)


# -- geometry (numpy only) ---------------------------------------------------


@dataclass(frozen=True)
class Crown:
    """The volume the leaf centres fill, in tree space (metres, Z up, trunk base at the origin).

    ``ellipsoids`` is empty for a cone and holds one ``(centre, semi_axes)``
    pair for an ellipsoid crown, several for lobes (their union).
    """

    kind: str
    base: float  # z of the crown's bottom
    top: float  # z of the crown's top (= tree height)
    radius: float  # horizontal radius of the bounding cylinder
    ellipsoids: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = ()

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: which of the (N, 3) ``points`` lie inside the crown (boundary included)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if self.kind == "cone":
            z = p[:, 2]
            r = np.hypot(p[:, 0], p[:, 1])
            return (z >= self.base) & (z <= self.top) & (r <= self.radius * (self.top - z) / (self.top - self.base))
        inside = np.zeros(p.shape[0], dtype=bool)
        for centre, axes in self.ellipsoids:
            inside |= np.sum(((p - np.asarray(centre)) / np.asarray(axes)) ** 2, axis=1) <= 1.0
        return inside

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n, 3) points uniformly distributed in the crown volume (rejection from the bounding box)."""
        lo = np.array([-self.radius, -self.radius, self.base])
        hi = np.array([self.radius, self.radius, self.top])
        kept: list[np.ndarray] = []
        have = 0
        accept = 0.5  # first guess of the acceptance rate; refined from each batch
        while have < n:
            batch = int(1.2 * (n - have) / accept) + 64
            p = lo + (hi - lo) * rng.random((batch, 3))
            inside = p[self.contains(p)]
            accept = max(inside.shape[0] / batch, 0.01)
            kept.append(inside)
            have += inside.shape[0]
        return np.concatenate(kept)[:n]


@dataclass(frozen=True, eq=False)  # arrays: compare fields with np.array_equal, not ==
class TreeGeometry:
    """Arrays of one generated tree, in metres, Z up.

    Leaf card ``i`` owns points ``4*i .. 4*i+3`` (counter-clockwise about its
    normal) and face ``i``; no point is shared between cards.
    """

    wood_points: np.ndarray  # (Vw, 3) float64
    wood_face_vertex_counts: np.ndarray  # (Fw,) int32: TUBE_SIDES quads and two TUBE_SIDES-gon caps per tube
    wood_face_vertex_indices: np.ndarray  # (sum counts,) int32
    leaf_points: np.ndarray  # (4 L, 3) float64
    leaf_face_vertex_counts: np.ndarray  # (L,) int32, all 4
    leaf_face_vertex_indices: np.ndarray  # (4 L,) int32, = arange(4 L)
    leaf_count: int
    branch_count: int  # tubes in the wood mesh, trunk included
    crown: Crown
    parameters: dict  # the build_tree arguments, for provenance (written to customLayerData)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frames(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors u, v with (u, v, axis) right-handed and orthonormal, for (N, 3) unit ``axis``."""
    helper = np.where(np.abs(axis[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = _unit(np.cross(axis, helper))
    return u, np.cross(axis, u)


def make_crown(kind: str, *, height: float, crown_radius: float, rng: np.random.Generator) -> Crown:
    """The crown volume for ``kind`` (see the module docstring); ``rng`` places the side lobes."""
    base = CROWN_BASE_FRACTION * height
    depth = height - base
    if kind == "cone":
        return Crown(kind, base, height, crown_radius)
    if kind == "ellipsoid":
        return Crown(kind, base, height, crown_radius, (((0.0, 0.0, base + depth / 2), (crown_radius, crown_radius, depth / 2)),))
    # lobes: a central lobe spanning the whole crown depth keeps the union connected;
    # side lobes touch the bounding cylinder from inside and stay between base and top.
    lobes = [((0.0, 0.0, base + depth / 2), (0.55 * crown_radius, 0.55 * crown_radius, depth / 2))]
    for k in range(SIDE_LOBES):
        rh = rng.uniform(0.4, 0.55) * crown_radius
        rz = rng.uniform(0.22, 0.32) * depth
        cz = rng.uniform(base + rz, height - rz)
        phi = 2 * math.pi * (k + rng.uniform(-0.2, 0.2)) / SIDE_LOBES
        d = crown_radius - rh
        lobes.append(((d * math.cos(phi), d * math.sin(phi), cz), (rh, rh, rz)))
    return Crown(kind, base, height, crown_radius, tuple(lobes))


def _grow_branches(rng: np.random.Generator, crown: Crown, height: float) -> list[tuple[np.ndarray, np.ndarray, float, float]]:
    """Trunk and three branch levels as straight tapered segments (p0, p1, r0, r1).

    "Space colonisation lite": every branch grows from a point on its parent to
    one of a cloud of attraction points sampled in the crown, so branch tips lie
    in the crown. Level-1 branches head for the crown point farthest out in
    their azimuth; deeper levels for the crown point nearest a jittered
    continuation of their parent.
    """
    targets = crown.sample(rng, 4000)
    depth = crown.top - crown.base
    trunk_top = crown.base + 0.7 * depth
    r_trunk = 0.012 * height + 0.025 * crown.radius
    r_min = 0.002 * height
    trunk = (np.zeros(3), np.array([0.0, 0.0, trunk_top]), r_trunk, 0.35 * r_trunk)
    segments = [trunk]

    def radius_at(seg, s):
        return seg[2] + s * (seg[3] - seg[2])

    golden = math.pi * (3.0 - math.sqrt(5.0))
    parents = []
    n1 = BRANCHING[0]
    for i in range(n1):
        z = crown.base + 0.1 * depth + (i + rng.uniform(0.2, 0.8)) / n1 * (trunk_top - crown.base - 0.1 * depth)
        attach = np.array([0.0, 0.0, z])
        phi = i * golden + rng.uniform(-0.3, 0.3)
        e = np.array([math.cos(phi), math.sin(phi)])
        along = targets[:, :2] @ e
        across = np.abs(targets[:, 0] * e[1] - targets[:, 1] * e[0])
        score = along - 0.5 * across + 0.3 * (targets[:, 2] - z)
        score[targets[:, 2] < z - 0.05 * depth] = -np.inf
        target = targets[int(np.argmax(score))]
        tip = attach + 0.9 * (target - attach)  # stop short of the crown's edge...
        if not crown.contains(tip)[0]:  # ...unless that leaves the crown (between lobes)
            tip = target
        r0 = max(0.5 * radius_at(trunk, z / trunk_top), r_min)
        parents.append((attach, tip, r0, max(0.3 * r0, r_min)))
    segments += parents

    for n_children in BRANCHING[1:]:
        children = []
        for p0, p1, r0, r1 in parents:
            direction = _unit(p1 - p0)
            length = float(np.linalg.norm(p1 - p0))
            for _ in range(n_children):
                s = rng.uniform(0.3, 0.9)
                attach = p0 + s * (p1 - p0)
                jitter = _unit(rng.standard_normal(3))
                want = attach + 0.55 * length * _unit(direction + 0.9 * jitter + np.array([0.0, 0.0, 0.2]))
                tip = targets[int(np.argmin(np.sum((targets - want) ** 2, axis=1)))]
                if np.linalg.norm(tip - attach) < 1e-6:
                    continue
                c0 = max(0.6 * (r0 + s * (r1 - r0)), r_min)
                children.append((attach, tip, c0, max(0.3 * c0, r_min)))
        segments += children
        parents = children
    return segments


def _tubes(segments, sides: int = TUBE_SIDES) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Capped tapered tubes, outward-facing (right-handed winding). Returns points, counts, indices."""
    p0 = np.array([s[0] for s in segments], dtype=np.float64)
    p1 = np.array([s[1] for s in segments], dtype=np.float64)
    r0 = np.array([s[2] for s in segments], dtype=np.float64)
    r1 = np.array([s[3] for s in segments], dtype=np.float64)
    m = p0.shape[0]
    u, v = _frames(_unit(p1 - p0))
    theta = 2.0 * np.pi * np.arange(sides) / sides
    ring = np.cos(theta)[None, :, None] * u[:, None, :] + np.sin(theta)[None, :, None] * v[:, None, :]  # (m, S, 3)
    bottom = p0[:, None, :] + r0[:, None, None] * ring
    top = p1[:, None, :] + r1[:, None, None] * ring
    points = np.concatenate([bottom, top], axis=1).reshape(-1, 3)

    j = np.arange(sides)
    jn = (j + 1) % sides
    # side quad j: bottom j -> bottom j+1 -> top j+1 -> top j, normal = tangent x axis = outward
    side = np.stack([j, jn, sides + jn, sides + j], axis=1).reshape(-1)
    # caps: the bottom one clockwise about the axis (normal -axis), the top one counter-clockwise (+axis)
    per_tube = np.concatenate([side, j[::-1], sides + j])
    indices = (per_tube[None, :] + 2 * sides * np.arange(m)[:, None]).reshape(-1)
    counts = np.tile(np.concatenate([np.full(sides, 4), [sides, sides]]), m)
    return points, counts.astype(np.int32), indices.astype(np.int32)


def _leaf_cards(rng: np.random.Generator, crown: Crown, n: int, size: float) -> np.ndarray:
    """(4 n, 3) corners of ``n`` square cards: centres uniform in the crown, normals uniform on the sphere."""
    centres = crown.sample(rng, n)
    normals = _unit(rng.standard_normal((n, 3)))  # isotropic Gaussian -> uniform direction
    u, v = _frames(normals)
    spin = rng.uniform(0.0, 2.0 * np.pi, n)[:, None]  # random in-plane rotation of each card
    t = np.cos(spin) * u + np.sin(spin) * v
    b = np.cross(normals, t)  # t x b = normal, so the corner order below winds counter-clockwise about it
    h = 0.5 * size
    corners = np.stack([-t - b, t - b, t + b, -t + b], axis=1) * h + centres[:, None, :]
    return corners.reshape(-1, 3)


def build_tree(*, leaves: int, leaf_size: float, crown: str, height: float, crown_radius: float, seed: int) -> TreeGeometry:
    """Generate one tree.

    Parameters
    ----------
    leaves : int
        Number of leaf cards (>= 1).
    leaf_size : float
        Side of each square card, metres (> 0).
    crown : {"ellipsoid", "cone", "lobes"}
        Crown shape; see the module docstring for its placement.
    height : float
        Tree height = crown top, metres (> 0).
    crown_radius : float
        Horizontal radius of the crown, metres (> 0).
    seed : int
        Seeds everything. Crown lobes, wood and leaves draw from separate
        streams, so changing ``leaves`` or ``leaf_size`` keeps the branches.

    Returns
    -------
    TreeGeometry
    """
    if crown not in CROWNS:
        raise ValueError(f"crown must be one of {', '.join(CROWNS)}, not {crown!r}")
    if int(leaves) != leaves or leaves < 1:
        raise ValueError(f"leaves must be a whole number >= 1, not {leaves!r}")
    for name, value in (("leaf_size", leaf_size), ("height", height), ("crown_radius", crown_radius)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive length in metres, not {value!r}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a whole number >= 0, not {seed!r}")
    leaves, seed = int(leaves), int(seed)
    crown_rng, wood_rng, leaf_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))

    shape = make_crown(crown, height=height, crown_radius=crown_radius, rng=crown_rng)
    segments = _grow_branches(wood_rng, shape, height)
    wood_points, wood_counts, wood_indices = _tubes(segments)
    leaf_points = _leaf_cards(leaf_rng, shape, leaves, leaf_size)
    return TreeGeometry(
        wood_points=wood_points,
        wood_face_vertex_counts=wood_counts,
        wood_face_vertex_indices=wood_indices,
        leaf_points=leaf_points,
        leaf_face_vertex_counts=np.full(leaves, 4, dtype=np.int32),
        leaf_face_vertex_indices=np.arange(4 * leaves, dtype=np.int32),
        leaf_count=leaves,
        branch_count=len(segments),
        crown=shape,
        parameters={
            "leaves": leaves,
            "leaf_size": float(leaf_size),
            "crown": crown,
            "height": float(height),
            "crown_radius": float(crown_radius),
            "seed": seed,
        },
    )


# -- USD writing -------------------------------------------------------------


def resolve_format(path: str | os.PathLike, file_format: str | None) -> str:
    """``usda`` or ``usdc`` for ``path``: the extension decides unless it is ``.usd`` (then
    ``file_format``, default ``usdc`` as in USD itself). Contradictions raise ValueError."""
    ext = Path(path).suffix.lower()
    implied = {".usda": "usda", ".usdc": "usdc", ".usd": None}
    if ext not in implied:
        raise ValueError(f"{path}: unsupported extension {ext or '(none)'!r}; use .usda, .usdc or .usd")
    if file_format is not None and file_format not in FORMATS:
        raise ValueError(f"format must be usda or usdc, not {file_format!r}")
    if implied[ext] and file_format and file_format != implied[ext]:
        raise ValueError(f"format {file_format} contradicts the extension of {path}; use a .{file_format} or .usd name")
    return implied[ext] or file_format or "usdc"


_TMP_NAMES = itertools.count()


@contextlib.contextmanager
def new_stage(path: str | os.PathLike, file_format: str | None = None) -> Iterator[Usd.Stage]:
    """A new Z-up, metre stage, written to ``path`` atomically when the ``with`` block succeeds.

    The root layer lives at a temporary name beside ``path`` while it is
    authored, so relative asset paths resolve as they will in the final file
    (extents of referenced geometry come out right); it is then saved and
    renamed onto ``path``. On error nothing is left behind.
    """
    path = Path(path)
    fmt = resolve_format(path, file_format)
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}-{next(_TMP_NAMES)}{path.suffix}")
    layer = Sdf.Layer.CreateNew(str(tmp), {"format": fmt} if path.suffix.lower() == ".usd" else {})
    if layer is None:
        raise OSError(f"USD cannot create {tmp}")
    try:
        stage = Usd.Stage.Open(layer)
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, UsdGeom.LinearUnits.meters)
        yield stage
        if not layer.Save():
            raise OSError(f"USD could not write {tmp}")
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def sun_rotate_xyz(azimuth_deg: float = SUN_AZIMUTH_DEG, elevation_deg: float = SUN_ELEVATION_DEG) -> Gf.Vec3f:
    """``xformOp:rotateXYZ`` that turns a DistantLight toward the sun in a Z-up stage.

    A DistantLight shines along its local -Z axis, so its +Z axis must point at
    the sun, d = (cos el cos az, cos el sin az, sin el). rotateXYZ applies X,
    then Y, then Z: Ry(90 - el) tips +Z over toward +X to elevation el, then
    Rz(az) swings it counter-clockwise to azimuth az.
    """
    return Gf.Vec3f(0.0, 90.0 - elevation_deg, azimuth_deg)


def add_lights(stage: Usd.Stage, root: str = "/Lights") -> None:
    """Sun (DistantLight, irradiance 1) and sky (DomeLight) under ``root``."""
    UsdGeom.Xform.Define(stage, root)
    sun = UsdLux.DistantLight.Define(stage, f"{root}/Sun")
    sun.CreateAngleAttr(SUN_ANGLE_DEG)
    sun.CreateIntensityAttr(1.0)
    # the light travels along its local -Z; rotateXYZ = (0, 90 - el, az) turns +Z toward the sun
    # at azimuth 45, elevation 60 (see sun_rotate_xyz)
    sun.AddRotateXYZOp().Set(sun_rotate_xyz())
    sky = UsdLux.DomeLight.Define(stage, f"{root}/Sky")
    sky.CreateIntensityAttr(SKY_INTENSITY)
    sky.CreateColorAttr(Gf.Vec3f(*SKY_COLOR))


def _material(stage: Usd.Stage, path: str, color: tuple[float, float, float], roughness: float) -> UsdShade.Material:
    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*color))
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


def _mesh(stage, path, points, counts, indices, *, material, color, is_leaf) -> UsdGeom.Mesh:
    mesh = UsdGeom.Mesh.Define(stage, path)
    p32 = np.ascontiguousarray(points, dtype=np.float32)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(p32))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(counts, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(indices, dtype=np.int32)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateDoubleSidedAttr(True)
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p32.min(axis=0))), Gf.Vec3f(*map(float, p32.max(axis=0)))]))
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(*color)]))
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("foliage:isLeaf", Sdf.ValueTypeNames.Bool, UsdGeom.Tokens.constant).Set(is_leaf)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    return mesh


def write_tree(path: str | os.PathLike, geometry: TreeGeometry, *, with_lights: bool = True, file_format: str | None = None) -> Path:
    """Write ``geometry`` as a Z-up, metre stage with defaultPrim ``/Tree`` (kind component).

    ``/Tree/Wood`` and ``/Tree/Leaves`` are Meshes bound to ``/Tree/Materials/Bark``
    and ``/Tree/Materials/Leaf`` (UsdPreviewSurface) with
    ``primvars:foliage:isLeaf`` false and true. With ``with_lights``, ``/Lights/Sun``
    and ``/Lights/Sky`` sit beside ``/Tree`` (outside the default prim, so
    references to the tree do not bring them along). ``file_format`` matters
    only for ``.usd`` paths (see :func:`resolve_format`).
    """
    with new_stage(path, file_format) as stage:
        layer = stage.GetRootLayer()
        layer.documentation = "Procedural tree from foliage-tools examples/make_tree.py"
        layer.customLayerData = {"foliage:generator": "examples/make_tree.py", "foliage:parameters": dict(geometry.parameters)}

        root = UsdGeom.Xform.Define(stage, "/Tree")
        Usd.ModelAPI(root).SetKind(Kind.Tokens.component)
        stage.SetDefaultPrim(root.GetPrim())
        UsdGeom.Scope.Define(stage, "/Tree/Materials")
        bark = _material(stage, "/Tree/Materials/Bark", BARK_COLOR, 0.9)
        leaf = _material(stage, "/Tree/Materials/Leaf", LEAF_COLOR, 0.6)
        _mesh(stage, "/Tree/Wood", geometry.wood_points, geometry.wood_face_vertex_counts, geometry.wood_face_vertex_indices,
              material=bark, color=BARK_COLOR, is_leaf=False)
        _mesh(stage, "/Tree/Leaves", geometry.leaf_points, geometry.leaf_face_vertex_counts, geometry.leaf_face_vertex_indices,
              material=leaf, color=LEAF_COLOR, is_leaf=True)
        if with_lights:
            add_lights(stage)
    return Path(path)


# -- command line ------------------------------------------------------------


def _positive(kind):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a {kind.__name__}") from None
        if not value > 0 or (kind is float and not math.isfinite(value)):
            raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
        return value

    parse.__name__ = kind.__name__
    return parse


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an int") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="make_tree.py",
        description="Write a seeded procedural tree (wood tubes + square leaf cards, sun and sky lights) as USD.",
        epilog="Example: python examples/make_tree.py --leaves 1500 --height 4 --crown-radius 1.2 --seed 1 --out examples/tree_small.usda",
    )
    ap.add_argument("--leaves", type=_positive(int), default=5000, help="number of leaf cards (default 5000)")
    ap.add_argument("--leaf-size", type=_positive(float), default=0.1, help="side of each square leaf card, metres (default 0.1)")
    ap.add_argument("--crown", choices=CROWNS, default="ellipsoid", help="crown shape (default ellipsoid)")
    ap.add_argument("--height", type=_positive(float), default=6.0, help="tree height = crown top, metres (default 6)")
    ap.add_argument("--crown-radius", type=_positive(float), default=2.0, help="horizontal crown radius, metres (default 2)")
    ap.add_argument("--seed", type=_non_negative_int, default=1, help="random seed; the same arguments give a byte-identical file (default 1)")
    ap.add_argument("--no-lights", action="store_true", help="leave out /Lights/Sun and /Lights/Sky")
    ap.add_argument("--format", choices=FORMATS, default=None, help="file format; only needed for a .usd name (default: from the extension, usdc for .usd)")
    ap.add_argument("--out", "-o", type=Path, default=Path("tree.usda"), help="output path, .usda/.usdc/.usd (default tree.usda)")
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = parser()
    args = ap.parse_args(argv)
    try:
        resolve_format(args.out, args.format)
    except ValueError as exc:
        ap.error(str(exc))
    geometry = build_tree(
        leaves=args.leaves, leaf_size=args.leaf_size, crown=args.crown, height=args.height, crown_radius=args.crown_radius, seed=args.seed
    )
    path = write_tree(args.out, geometry, with_lights=not args.no_lights, file_format=args.format)
    print(
        f"wrote {path}: {geometry.leaf_count} leaves, {geometry.branch_count} branch tubes "
        f"({geometry.wood_face_vertex_counts.shape[0]} wood faces), {path.stat().st_size / 1e6:.2f} MB"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
