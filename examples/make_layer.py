#!/usr/bin/env python3
"""A seeded uniform random leaf layer written as USD: the plane-parallel test scene.

A box of ``size`` X × Y by ``thickness`` H metres (Z up; x, y centred on the
origin, z from 0 to H) filled with N square leaf cards of side ``leaf_size``
(one ``Mesh``, ``/Layer/Leaves``), each card with its own four points, card
centres uniform in the box and orientations uniform (Haar-random rotations,
so normals are uniform on the sphere: G = 0.5). N is chosen from the one-sided
leaf-area index, N = round(LAI · X · Y / leaf_size²), so the leaf-area density
is LAD = LAI / H and, away from the sides, the optical depth at depth z_top − z
below the top is τ = G · LAI · (z_top − z) / H (Beer–Lambert for the direct sun:
E_direct = 0.5 exp(−τ / μ0), μ0 = sin elevation). No wood. A sun
(``UsdLux.DistantLight``, ``/Lights/Sun``) at ``sun`` = (azimuth, elevation)
degrees; a sky only on request.

Library use (pure numpy, then one writer)::

    geometry = build_layer(size=(10.0, 10.0), thickness=1.5, lai=3.0, leaf_size=0.1, seed=1)
    write_layer_stage("layer.usda", geometry, sun=(0.0, 60.0))

Command line: ``python examples/make_layer.py --help``. The same arguments
give a byte-identical file.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Gf, Kind, Usd, UsdGeom, UsdLux

sys.path.insert(0, str(Path(__file__).resolve().parent))
import make_tree  # noqa: E402  (a sibling script, not a package: stage, lights and mesh helpers)

#: Default sun of this scene: azimuth 0 (toward +X), elevation 60 degrees.
SUN_DEFAULT = (0.0, 60.0)


@dataclass(frozen=True, eq=False)  # arrays: compare fields with np.array_equal, not ==
class LayerGeometry:
    """Arrays of one generated layer, in metres, Z up.

    Card ``i`` owns points ``4*i .. 4*i+3`` (counter-clockwise about its
    normal) and face ``i``; no point is shared between cards.
    """

    points: np.ndarray  # (4 N, 3) float64
    face_vertex_counts: np.ndarray  # (N,) int32, all 4
    face_vertex_indices: np.ndarray  # (4 N,) int32, = arange(4 N)
    centres: np.ndarray  # (N, 3) float64 card centres
    normals: np.ndarray  # (N, 3) float64 unit card normals
    leaf_count: int
    lo: np.ndarray  # (3,) box corner the centres fill: (-X/2, -Y/2, 0)
    hi: np.ndarray  # (3,) opposite corner: (X/2, Y/2, H)
    parameters: dict  # the build_layer arguments, for provenance (written to customLayerData)

    @property
    def lad(self) -> float:
        """One-sided leaf-area density, m²/m³ (= LAI / H up to the rounding of N)."""
        side = self.parameters["leaf_size"]
        return self.leaf_count * side * side / float(np.prod(self.hi - self.lo))

    def triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """(2 N, 3, 3) triangles (card i: 2i = corners 0,1,2 and 2i+1 = 0,2,3, the fan USD readers use)
        and the (2 N,) card id of each."""
        c = self.points.reshape(-1, 4, 3)
        tri = np.empty((2 * c.shape[0], 3, 3))
        tri[0::2] = c[:, [0, 1, 2]]
        tri[1::2] = c[:, [0, 2, 3]]
        return tri, np.repeat(np.arange(c.shape[0]), 2)


def build_layer(*, size=(10.0, 10.0), thickness: float = 1.5, lai: float = 3.0, leaf_size: float = 0.1, seed: int = 1) -> LayerGeometry:
    """Generate one layer (see the module docstring).

    Parameters
    ----------
    size : (float, float)
        Horizontal extent X, Y of the box the card centres fill, metres (> 0).
    thickness : float
        Height H of the box, metres (> 0); centres have 0 <= z <= H.
    lai : float
        One-sided leaf-area index (> 0): N = round(lai · X · Y / leaf_size²) cards (at least 1).
    leaf_size : float
        Side of each square card, metres (> 0).
    seed : int
        Seeds everything.
    """
    x, y = (float(v) for v in size)
    for name, value in (("size X", x), ("size Y", y), ("thickness", thickness), ("lai", lai), ("leaf_size", leaf_size)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number, not {value!r}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a whole number >= 0, not {seed!r}")
    n = max(1, int(round(lai * x * y / (leaf_size * leaf_size))))
    rng = np.random.default_rng(int(seed))
    lo = np.array([-x / 2, -y / 2, 0.0])
    hi = np.array([x / 2, y / 2, float(thickness)])
    centres = lo + rng.random((n, 3)) * (hi - lo)
    # Haar-random rotation per card: QR of a Gaussian matrix with the signs of R's diagonal
    # moved into Q (Mezzadri 2007), as tests/unit/test_reference.py random_cards does.
    q, r = np.linalg.qr(rng.standard_normal((n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    u = q[:, :, 0] * (0.5 * leaf_size)
    v = q[:, :, 1] * (0.5 * leaf_size)
    corners = np.stack([centres - u - v, centres + u - v, centres + u + v, centres - u + v], axis=1)
    normals = np.cross(q[:, :, 0], q[:, :, 1])  # corners wind counter-clockwise about it
    return LayerGeometry(
        points=corners.reshape(-1, 3),
        face_vertex_counts=np.full(n, 4, dtype=np.int32),
        face_vertex_indices=np.arange(4 * n, dtype=np.int32),
        centres=centres,
        normals=normals,
        leaf_count=n,
        lo=lo,
        hi=hi,
        parameters={"size_x": x, "size_y": y, "thickness": float(thickness), "lai": float(lai), "leaf_size": float(leaf_size), "seed": int(seed)},
    )


# -- USD writing -------------------------------------------------------------


def write_layer_stage(
    path: str | os.PathLike,
    geometry: LayerGeometry,
    *,
    sun: tuple[float, float] | None = SUN_DEFAULT,
    sky: bool = False,
    file_format: str | None = None,
) -> Path:
    """Write ``geometry`` as a Z-up, metre stage with defaultPrim ``/Layer`` (Xform, kind component).

    ``/Layer/Leaves`` is one Mesh of the cards, ``primvars:foliage:isLeaf`` true,
    bound to ``/Layer/Materials/Leaf``. ``sun`` = (azimuth, elevation) degrees
    puts a DistantLight at ``/Lights/Sun`` (None: no sun); ``sky`` adds
    make_tree.py's DomeLight at ``/Lights/Sky``. The lights sit outside
    ``/Layer``. ``file_format`` matters only for ``.usd`` paths.
    """
    with make_tree.new_stage(path, file_format) as stage:
        layer = stage.GetRootLayer()
        layer.documentation = "Uniform random leaf layer from foliage-tools examples/make_layer.py"
        params = dict(geometry.parameters)
        if sun is not None:  # customLayerData holds scalars here (a list becomes an unreadable VtValue vector)
            params["sun_azimuth"], params["sun_elevation"] = float(sun[0]), float(sun[1])
        params["sky"] = bool(sky)
        layer.customLayerData = {"foliage:generator": "examples/make_layer.py", "foliage:parameters": params}

        root = UsdGeom.Xform.Define(stage, "/Layer")
        Usd.ModelAPI(root).SetKind(Kind.Tokens.component)
        stage.SetDefaultPrim(root.GetPrim())
        UsdGeom.Scope.Define(stage, "/Layer/Materials")
        leaf = make_tree._material(stage, "/Layer/Materials/Leaf", make_tree.LEAF_COLOR, 0.6)
        make_tree._mesh(stage, "/Layer/Leaves", geometry.points, geometry.face_vertex_counts, geometry.face_vertex_indices,
                        material=leaf, color=make_tree.LEAF_COLOR, is_leaf=True)
        if sun is not None or sky:
            UsdGeom.Xform.Define(stage, "/Lights")
        if sun is not None:
            light = UsdLux.DistantLight.Define(stage, "/Lights/Sun")
            light.CreateAngleAttr(make_tree.SUN_ANGLE_DEG)
            light.CreateIntensityAttr(1.0)
            light.AddRotateXYZOp().Set(make_tree.sun_rotate_xyz(*sun))  # +Z toward the sun (see sun_rotate_xyz)
        if sky:
            dome = UsdLux.DomeLight.Define(stage, "/Lights/Sky")
            dome.CreateIntensityAttr(make_tree.SKY_INTENSITY)
            dome.CreateColorAttr(Gf.Vec3f(*make_tree.SKY_COLOR))
    return Path(path)


# -- command line ------------------------------------------------------------


def _sun(text: str) -> tuple[float, float]:
    try:
        az, el = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not AZ,EL (two numbers in degrees)") from None
    if not (math.isfinite(az) and 0.0 < el <= 90.0):
        raise argparse.ArgumentTypeError(f"elevation must be in (0, 90] degrees, got {text}")
    return az, el


def parser() -> argparse.ArgumentParser:
    pos = make_tree._positive(float)
    ap = argparse.ArgumentParser(
        prog="make_layer.py",
        description="Write a seeded uniform random layer of square leaf cards (and a sun) as USD.",
        epilog="Example: python examples/make_layer.py --size 10 10 --thickness 1.5 --lai 3 --sun 0,60 --out examples/generated/layer.usdc",
    )
    ap.add_argument("--size", type=pos, nargs=2, metavar=("X", "Y"), default=[10.0, 10.0], help="horizontal extent, metres (default 10 10)")
    ap.add_argument("--thickness", type=pos, default=1.5, help="layer height H, metres (default 1.5)")
    ap.add_argument("--lai", type=pos, default=3.0, help="one-sided leaf-area index; N = LAI*X*Y/side^2 cards (default 3)")
    ap.add_argument("--leaf-size", type=pos, default=0.1, help="side of each square card, metres (default 0.1)")
    ap.add_argument("--sun", type=_sun, default=SUN_DEFAULT, metavar="AZ,EL", help="sun azimuth,elevation in degrees (default 0,60)")
    ap.add_argument("--no-sun", action="store_true", help="leave out /Lights/Sun")
    ap.add_argument("--sky", action="store_true", help="add a DomeLight /Lights/Sky (default: none)")
    ap.add_argument("--seed", type=make_tree._non_negative_int, default=1, help="random seed; the same arguments give a byte-identical file (default 1)")
    ap.add_argument("--format", choices=make_tree.FORMATS, default=None, help="file format; only needed for a .usd name")
    ap.add_argument("--out", "-o", type=Path, default=Path("layer.usda"), help="output path, .usda/.usdc/.usd (default layer.usda)")
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = parser()
    args = ap.parse_args(argv)
    try:
        make_tree.resolve_format(args.out, args.format)
    except ValueError as exc:
        ap.error(str(exc))
    geometry = build_layer(size=args.size, thickness=args.thickness, lai=args.lai, leaf_size=args.leaf_size, seed=args.seed)
    path = write_layer_stage(args.out, geometry, sun=None if args.no_sun else args.sun, sky=args.sky, file_format=args.format)
    print(f"wrote {path}: {geometry.leaf_count} leaf cards, LAD {geometry.lad:.4g} m^2/m^3, {path.stat().st_size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
