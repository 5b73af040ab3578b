#!/usr/bin/env python3
"""A small seeded forest that reuses one tree asset in both of USD's instancing styles.

``/World`` (Z-up, metres, the default prim) holds:

- ``/World/Trees/Tree_00`` ... : native instances, each an Xform with
  ``instanceable = true`` that references the tree file (relative asset path,
  its defaultPrim) with its own translate / rotateZ / scale;
- ``/World/Grove``: a ``UsdGeom.PointInstancer`` whose single prototype
  ``/World/Grove/Prototypes/TreeProto`` references the same tree file, with
  positions on a ring around the native trees, orientations about +Z and
  uniform scales (``protoIndices`` all 0);
- ``/Lights/Sun`` and ``/Lights/Sky``, the same lights as ``make_tree.py``.

Command line: ``python examples/make_forest.py --help``. The tree file must
exist (write it with ``make_tree.py`` first): its bounds set the spacing.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Gf, Kind, Usd, UsdGeom, Vt

sys.path.insert(0, str(Path(__file__).resolve().parent))
import make_tree  # noqa: E402  (a sibling script, not a package)

HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class ForestLayout:
    """Where the trees go, in metres (Z up). Angles are degrees about +Z."""

    tree_positions: np.ndarray  # (T, 3)
    tree_angles: np.ndarray  # (T,)
    tree_scales: np.ndarray  # (T,)
    grove_positions: np.ndarray  # (G, 3)
    grove_angles: np.ndarray  # (G,)
    grove_scales: np.ndarray  # (G,)
    grove_prototypes: np.ndarray | None = None  # (G,) index of each point instance's tree file; None: all the first


def plan_forest(*, trees: int, grove: int, tree_radius: float, seed: int) -> ForestLayout:
    """Place ``trees`` native instances on a jittered square grid around the origin and
    ``grove`` point instances on a ring outside it, for trees whose crowns fit in a
    circle of ``tree_radius`` about their trunk (before scaling).

    Scales are in [0.8, 1.25], so two crowns never overlap when their trunks are at
    least ``spacing = 2.6 * tree_radius`` apart; the grid, its jitter and the ring
    radius are chosen to keep every pair at least that far apart.
    """
    if trees < 0 or grove < 0:
        raise ValueError(f"trees and grove must be >= 0, got {trees} and {grove}")
    if not (math.isfinite(tree_radius) and tree_radius > 0):
        raise ValueError(f"tree_radius must be > 0, got {tree_radius}")
    rng = np.random.default_rng(seed)
    spacing = 2.6 * tree_radius
    # grid pitch 1.2 spacings, jitter at most 0.05 spacings per axis: neighbours stay > 1.05 spacings apart
    side = max(1, math.ceil(math.sqrt(trees)))
    cells = np.array([(i % side, i // side) for i in range(trees)], dtype=np.float64).reshape(-1, 2)
    tree_xy = (cells - (side - 1) / 2.0) * 1.2 * spacing + rng.uniform(-0.05, 0.05, (trees, 2)) * spacing
    tree_angles = rng.uniform(0.0, 360.0, trees)
    tree_scales = rng.uniform(0.8, 1.25, trees)

    # ring: one spacing beyond the farthest grid tree, and wide enough that neighbours on it
    # (angular jitter +-0.1 of a slot, so at least 0.8 slot apart) are a spacing apart;
    # extra radial jitter only moves them farther apart
    corner = (side - 1) / 2.0 * 1.2 * spacing * math.sqrt(2.0) + 0.1 * spacing if trees else 0.0
    ring = corner + spacing
    if grove > 1:
        ring = max(ring, 1.05 * spacing / (2.0 * math.sin(math.pi * 0.8 / grove)))
    phi = 2.0 * math.pi * (np.arange(grove) + rng.uniform(-0.1, 0.1, grove)) / max(grove, 1)
    radius = ring + rng.uniform(0.0, 0.4, grove) * spacing
    grove_xy = np.stack([radius * np.cos(phi), radius * np.sin(phi)], axis=1).reshape(-1, 2)
    grove_angles = rng.uniform(0.0, 360.0, grove)
    grove_scales = rng.uniform(0.8, 1.25, grove)

    def lift(xy):
        return np.concatenate([xy, np.zeros((xy.shape[0], 1))], axis=1)

    return ForestLayout(lift(tree_xy), tree_angles, tree_scales, lift(grove_xy), grove_angles, grove_scales)


def plan_stand(*, side: int, tree_radius: float, seed: int, prototypes: int = 1) -> ForestLayout:
    """A ``side`` x ``side`` stand for the PointInstancer: trunks on a square grid one crown diameter apart
    (``2 * tree_radius``, so neighbouring crowns touch), random rotations about +Z, scale 1, no native trees;
    with ``prototypes`` > 1, each instance one of that many tree files, at random.

    Instance ``i`` sits in row ``i // side``, column ``i % side``; the centre one (odd ``side``) is
    ``side * side // 2``.
    """
    if side < 1:
        raise ValueError(f"the stand needs at least 1 x 1 trees, got {side}")
    if not (math.isfinite(tree_radius) and tree_radius > 0):
        raise ValueError(f"tree_radius must be > 0, got {tree_radius}")
    rng = np.random.default_rng(seed)
    n = side * side
    cells = np.array([(i % side, i // side) for i in range(n)], dtype=np.float64)
    xy = (cells - (side - 1) / 2.0) * 2.0 * tree_radius
    empty = np.zeros((0, 3))
    angles = rng.uniform(0.0, 360.0, n)
    which = rng.integers(0, prototypes, n) if prototypes > 1 else None  # drawn last: one tree file keeps its bytes
    return ForestLayout(empty, np.zeros(0), np.zeros(0), np.concatenate([xy, np.zeros((n, 1))], axis=1),
                        angles, np.ones(n), which)


def tree_radius_of(tree_path: str | os.PathLike) -> float:
    """Horizontal reach of the tree file's default prim from its trunk axis (the origin), metres.

    Taken from the axis-aligned bounding box: the largest |x| or |y| of its
    corners, which bounds a round crown centred on the trunk.
    """
    stage = Usd.Stage.Open(str(tree_path))
    prim = stage.GetDefaultPrim()
    if not prim:
        raise ValueError(f"@{tree_path}@ has no defaultPrim; it cannot be referenced without a prim path")
    box = UsdGeom.BBoxCache(Usd.TimeCode.Default(), [UsdGeom.Tokens.default_]).ComputeWorldBound(prim).ComputeAlignedRange()
    if box.IsEmpty():
        raise ValueError(f"@{tree_path}@: <{prim.GetPath()}> has no geometry bounds")
    lo, hi = box.GetMin(), box.GetMax()
    return float(max(abs(lo[0]), abs(hi[0]), abs(lo[1]), abs(hi[1])))


def relative_asset_path(target: Path, layer_path: Path) -> str:
    """``target`` relative to the directory of ``layer_path``, anchored with ``./`` when it is beside it."""
    rel = Path(os.path.relpath(target.resolve(), layer_path.resolve().parent)).as_posix()
    return rel if rel.startswith("../") else f"./{rel}"


def write_forest(path: str | os.PathLike, tree_path, layout: ForestLayout, *,
                 with_lights: bool = True, file_format: str | None = None, parameters: dict | None = None) -> Path:
    """Write the forest stage at ``path``, referencing ``tree_path`` (one file, or a list: the point instancer's
    prototypes, ``layout.grove_prototypes`` choosing among them) by relative asset paths."""
    tree_paths = [Path(t) for t in tree_path] if isinstance(tree_path, (list, tuple)) else [Path(tree_path)]
    path = Path(path)
    assets = [relative_asset_path(t, path) for t in tree_paths]
    asset = assets[0]
    with make_tree.new_stage(path, file_format) as stage:
        layer = stage.GetRootLayer()
        layer.documentation = "Procedural forest from foliage-tools examples/make_forest.py"
        layer.customLayerData = {"foliage:generator": "examples/make_forest.py", "foliage:parameters": dict(parameters or {})}

        world = UsdGeom.Xform.Define(stage, "/World")
        Usd.ModelAPI(world).SetKind(Kind.Tokens.assembly)
        stage.SetDefaultPrim(world.GetPrim())
        trees = UsdGeom.Xform.Define(stage, "/World/Trees")
        Usd.ModelAPI(trees).SetKind(Kind.Tokens.group)
        for i, (pos, angle, scale) in enumerate(zip(layout.tree_positions, layout.tree_angles, layout.tree_scales)):
            xf = UsdGeom.Xform.Define(stage, f"/World/Trees/Tree_{i:02d}")
            xf.GetPrim().GetReferences().AddReference(asset)
            xf.GetPrim().SetInstanceable(True)
            xf.AddTranslateOp().Set(Gf.Vec3d(*map(float, pos)))
            xf.AddRotateZOp().Set(float(angle))
            xf.AddScaleOp().Set(Gf.Vec3f(float(scale)))

        grove = UsdGeom.PointInstancer.Define(stage, "/World/Grove")
        UsdGeom.Scope.Define(stage, "/World/Grove/Prototypes")
        targets = []
        for k, a in enumerate(assets):
            proto = UsdGeom.Xform.Define(stage, "/World/Grove/Prototypes/TreeProto" + (f"_{k}" if k else ""))
            proto.GetPrim().GetReferences().AddReference(a)
            # instanceable too, so the grove shares the native prototype of /World/Trees and the tree is read once
            proto.GetPrim().SetInstanceable(True)
            targets.append(proto.GetPath())
        grove.CreatePrototypesRel().SetTargets(targets)
        n = layout.grove_positions.shape[0]
        which = np.zeros(n) if layout.grove_prototypes is None else layout.grove_prototypes
        if len(which) and int(np.max(which)) >= len(assets):
            raise ValueError(f"the layout uses {int(np.max(which)) + 1} tree files, {len(assets)} given")
        grove.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(which, dtype=np.int32)))
        grove.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(layout.grove_positions, dtype=np.float32)))
        half = np.radians(layout.grove_angles) / 2.0  # rotation about +Z: q = (cos a/2, 0, 0, sin a/2)
        grove.CreateOrientationsAttr(Vt.QuathArray([Gf.Quath(float(np.cos(h)), 0.0, 0.0, float(np.sin(h))) for h in half]))
        scales = np.repeat(layout.grove_scales[:, None], 3, axis=1).astype(np.float32)
        grove.CreateScalesAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(scales)))
        t = Usd.TimeCode.Default()
        extent = grove.ComputeExtentAtTime(t, t)  # the reference resolves: the layer already sits beside `path`
        if extent is None or len(extent) != 2:
            raise ValueError(f"cannot compute the bounds of @{asset}@ from {path}; is it a tree file with geometry?")
        grove.CreateExtentAttr(extent)
        if with_lights:
            make_tree.add_lights(stage)
    return path


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="make_forest.py",
        description="Write a seeded forest: native instanceable references and a PointInstancer of one tree file, plus sun and sky.",
        epilog="Example: python examples/make_forest.py --tree examples/tree_small.usda --out examples/forest_small.usda",
    )
    ap.add_argument("--tree", type=Path, action="append", default=None,
                    help="tree file to reference (default: tree_small.usda beside this script); with --stand, give it "
                         "several times for a stand of several prototypes, each instance one of them at random")
    ap.add_argument("--trees", type=int, default=4, help="native instanceable trees under /World/Trees (default 4)")
    ap.add_argument("--grove", type=int, default=12, help="PointInstancer instances in /World/Grove (default 12)")
    ap.add_argument("--stand", type=int, default=0, metavar="N",
                    help="instead of --trees and --grove: an N x N PointInstancer stand, trunks one crown diameter "
                         "apart so the crowns touch, random rotations (default 0: off)")
    ap.add_argument("--seed", type=int, default=7, help="random seed; the same arguments give a byte-identical file (default 7)")
    ap.add_argument("--no-lights", action="store_true", help="leave out /Lights/Sun and /Lights/Sky")
    ap.add_argument("--format", choices=make_tree.FORMATS, default=None, help="file format; only needed for a .usd name (default: from the extension)")
    ap.add_argument("--out", "-o", type=Path, default=Path("forest.usda"), help="output path, .usda/.usdc/.usd (default forest.usda)")
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = parser()
    args = ap.parse_args(argv)
    if args.trees < 0 or args.grove < 0 or args.seed < 0 or args.stand < 0:
        ap.error("--trees, --grove, --stand and --seed must be >= 0")
    trees = args.tree or [HERE / "tree_small.usda"]
    if len(trees) > 1 and not args.stand:
        ap.error("several --tree files need --stand (the stand's point instancer chooses among them)")
    for t in trees:
        if not t.is_file():
            ap.error(f"tree file {t} does not exist; write it first with examples/make_tree.py")
    try:
        make_tree.resolve_format(args.out, args.format)
        radius = max(tree_radius_of(t) for t in trees)
    except ValueError as exc:
        ap.error(str(exc))
    rel = [relative_asset_path(t, args.out) for t in trees]
    tree_param = ", ".join(rel)  # (a string: crate files cannot pack a list of strings in layer data)
    if args.stand:
        layout = plan_stand(side=args.stand, tree_radius=radius, seed=args.seed, prototypes=len(trees))
        params = {"tree": tree_param, "stand": args.stand, "seed": args.seed}
    else:
        layout = plan_forest(trees=args.trees, grove=args.grove, tree_radius=radius, seed=args.seed)
        params = {"tree": tree_param, "trees": args.trees, "grove": args.grove, "seed": args.seed}
    path = write_forest(args.out, trees if len(trees) > 1 else trees[0], layout, with_lights=not args.no_lights,
                        file_format=args.format, parameters=params)
    print(f"wrote {path}: {len(layout.tree_positions)} instanceable trees + a PointInstancer of {len(layout.grove_positions)}, "
          f"referencing {', '.join(f'@{relative_asset_path(t, path)}@' for t in trees)}, {path.stat().st_size / 1e3:.1f} kB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
