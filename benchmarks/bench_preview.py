"""Benchmark the previewer's frame time on synthetic crowns and an instanced forest.

Usage::

    python benchmarks/bench_preview.py [--size 1024x1024] [--triangles 10000 100000 1000000]
                                       [--forest 100] [--lod 0.25] [--frames 5] [--samples 4] [--shadow-size 2048]

Scenes:

* ``cards N``: N/2 square leaf cards (2 triangles each, side 0.05 × crown
  radius, uniformly random orientation) with centres uniform in a ball, one
  instance, ground plane on.
* ``forest K``: K instances of ``examples/tree_small.usda`` (leaves and wood)
  on a jittered grid, random rotation about up and scale 0.8-1.2, drawn with
  instancing (one vertex buffer per material, one matrix per instance).
* ``forest K, lod F``: the same forest with ``--lod F`` (:mod:`foliage_tools.preview.lod`):
  wood simplified to F of its triangles, instances farther than 8 tree radii from
  the camera at F² wood and F of their leaves (area-compensated). The ``lod s``
  column is the one-off cost of simplifying (cached per prototype and level).
* ``forest K, smax``: the same forest drawn with ``--method smax``: Boulanger's
  one-bounce model evaluated per vertex (``shaders/boulanger.glsl``) from s_max
  per leaf (random here: the cost does not depend on the values) and τ.
* ``forest K, lb relit``: the same forest drawn with ``--method lb`` from 18 relighting
  bases per vertex (random values): every instance blends the three bases that bracket
  the sun in its own frame (``scene.vert.glsl``, LB_RELIGHT), weights recomputed per frame.

For each scene: upload time (GL context, buffers, programs: the first frame
compiles shaders, so it is reported separately), then the median over
``--frames`` frames of

* ``frame``: a full frame with a new sun direction each time (shadow pass +
  main pass + MSAA resolve + read-back of the float image), and
* ``cached``: the same camera and sun again (the shadow map is reused).

Timings are wall clock on whatever GL the machine gives (Mesa llvmpipe on a
CPU-only machine: expect noisy numbers on a shared host).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from foliage_tools.pipeline.preview import parse_size  # noqa: E402
from foliage_tools.preview.camera import direction_from_angles, orbit_camera  # noqa: E402
from foliage_tools.preview.lod import LodParams, apply_lod  # noqa: E402
from foliage_tools.preview.renderer import DrawMesh, DrawPrototype, DrawScene, Ground, Lighting, Renderer  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
UP = np.array([0.0, 0.0, 1.0])


def card_corners(n_cards: int, rng: np.random.Generator, radius: float = 1.0) -> np.ndarray:
    """(6 n, 3) float32 un-indexed corners of n random cards in a ball lifted above the ground."""
    side = 0.05 * radius
    d = rng.normal(size=(n_cards, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = d * radius * rng.uniform(size=(n_cards, 1)) ** (1 / 3) + [0.0, 0.0, 1.5 * radius]
    q, r = np.linalg.qr(rng.normal(size=(n_cards, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    u, v = q[:, :, 0] * side / 2, q[:, :, 1] * side / 2
    a, b, cc, dd = c - u - v, c + u - v, c + u + v, c - u + v
    return np.stack([a, b, cc, a, cc, dd], axis=1).reshape(-1, 3).astype(np.float32)


def cards_scene(triangles: int, rng: np.random.Generator) -> DrawScene:
    mesh = DrawMesh(corners=card_corners(triangles // 2, rng), leaf=True)
    return DrawScene((DrawPrototype((mesh,), np.eye(4)[None]),), UP)


def forest_scene(count: int, rng: np.random.Generator) -> DrawScene:
    from foliage_tools.scene.read import read_scene

    tree = REPO / "examples" / "tree_small.usda"
    if not tree.exists():
        raise SystemExit(f"{tree} is missing: run examples/make_tree.py first (see examples/README.md)")
    scene, _ = read_scene(tree)
    base = DrawScene.from_scene(scene).prototypes[0]
    side = int(np.ceil(np.sqrt(count)))
    spacing = 3.0
    transforms = []
    for k in range(count):
        i, j = divmod(k, side)
        a = rng.uniform(0, 2 * np.pi)
        s = rng.uniform(0.8, 1.2)
        m = np.eye(4)
        m[:3, :3] = s * np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        m[:3, 3] = [(i - side / 2) * spacing + rng.uniform(-0.5, 0.5), (j - side / 2) * spacing + rng.uniform(-0.5, 0.5), 0.0]
        transforms.append(m @ scene.instances[0].transform)
    return DrawScene((DrawPrototype(base.meshes, np.array(transforms)),), UP)


def with_smax(scene: DrawScene, rng: np.random.Generator) -> DrawScene:
    """The scene with random per-leaf s_max on every leaf mesh and τ = 2 (for timing the smax shader)."""
    protos = []
    for p in scene.prototypes:
        meshes = []
        for m in p.meshes:
            if m.leaf:
                per_tri = rng.uniform(0.0, 1.0, size=(m.triangle_count, 8)).astype(np.float32)
                m = DrawMesh(corners=m.corners, leaf=True, indirect=m.indirect, smax=np.repeat(per_tri, 3, axis=0))
            meshes.append(m)
        protos.append(DrawPrototype(tuple(meshes), p.transforms, tau=2.0))
    return DrawScene(tuple(protos), scene.up)


def with_lb_bases(scene: DrawScene, rng: np.random.Generator) -> DrawScene:
    """The scene with random E_scattered of the 18 LB bases at every leaf corner (for timing the relit lb method)."""
    protos = []
    for p in scene.prototypes:
        meshes = tuple(
            DrawMesh(corners=m.corners, leaf=True, indirect=m.indirect,
                     lb_bases=rng.uniform(0.0, 0.1, size=(18,) + m.corners.shape).astype(np.float32)) if m.leaf else m
            for m in p.meshes
        )
        protos.append(DrawPrototype(meshes, p.transforms))
    return DrawScene(tuple(protos), scene.up)


def bench(name: str, scene: DrawScene, *, width: int, height: int, frames: int, samples: int, shadow_size: int,
          lod: float | None = None, method: str | None = None) -> dict:
    bounds = scene.bounds()
    ground = Ground.under(bounds, UP)
    cam = orbit_camera(bounds, width=width, height=height, up_axis="Z", azimuth=30, elevation=20, clip_bounds=ground.bounds(UP))
    lod_seconds = 0.0
    if lod is not None:
        t0 = time.perf_counter()
        scene = apply_lod(scene, cam.position, LodParams(lod))
        lod_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    renderer = Renderer(scene, samples=samples, shadow_size=shadow_size)
    upload = time.perf_counter() - t0
    with renderer:
        t0 = time.perf_counter()
        renderer.render(cam, Lighting(direction_from_angles(0, 50, "Z")), method=method, ground=ground)  # compiles shaders
        first = time.perf_counter() - t0
        full, cached = [], []
        for k in range(frames):
            light = Lighting(direction_from_angles(45 + 7 * (k + 1), 50, "Z"))
            t0 = time.perf_counter()
            renderer.render(cam, light, method=method, ground=ground)
            full.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            renderer.render(cam, light, method=method, ground=ground)
            cached.append(time.perf_counter() - t0)
        gl = renderer.renderer_name
        ms = renderer.samples or 1
    return {
        "scene": name,
        "triangles": scene.triangle_count,
        "instances": scene.instance_count,
        "upload": upload,
        "lod": lod_seconds,
        "first": first,
        "frame": statistics.median(full),
        "cached": statistics.median(cached),
        "gl": gl,
        "samples": ms,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="1024x1024")
    ap.add_argument("--triangles", type=int, nargs="*", default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--forest", type=int, nargs="*", default=[100], help="forest sizes (instances); none to skip")
    ap.add_argument("--lod", type=float, nargs="*", default=[0.25], help="LOD fractions for extra forest rows; none to skip")
    ap.add_argument("--no-smax", action="store_true", help="skip the forest row drawn with the smax method")
    ap.add_argument("--no-lb", action="store_true", help="skip the forest row drawn with the relit lb method")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--samples", type=int, default=4)
    ap.add_argument("--shadow-size", type=int, default=2048)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    width, height = parse_size(args.size)
    rng = np.random.default_rng(args.seed)
    rows = []
    for n in args.triangles:
        rows.append(bench(f"cards {n:,}", cards_scene(n, rng), width=width, height=height, frames=args.frames,
                          samples=args.samples, shadow_size=args.shadow_size))
    for k in args.forest:
        forest = forest_scene(k, rng)
        rows.append(bench(f"forest {k} x tree_small", forest, width=width, height=height, frames=args.frames,
                          samples=args.samples, shadow_size=args.shadow_size))
        if not args.no_smax:
            rows.append(bench(f"forest {k}, smax", with_smax(forest, rng), width=width, height=height, frames=args.frames,
                              samples=args.samples, shadow_size=args.shadow_size, method="smax"))
        if not args.no_lb:
            rows.append(bench(f"forest {k}, lb relit", with_lb_bases(forest, rng), width=width, height=height, frames=args.frames,
                              samples=args.samples, shadow_size=args.shadow_size, method="lb"))
        for f in args.lod:
            rows.append(bench(f"forest {k}, lod {f:g}", forest, width=width, height=height, frames=args.frames,
                              samples=args.samples, shadow_size=args.shadow_size, lod=f))
    print(f"foliage preview frame times at {width}x{height}, {rows[0]['samples']} samples/pixel (supersampled), shadow map {args.shadow_size}², "
          f"median of {args.frames} frames; GL: {rows[0]['gl']}")
    head = (f"{'scene':<26} {'triangles':>10} {'inst.':>6} {'lod s':>6} {'upload s':>9} {'1st frame s':>12} {'frame s':>8} "
            f"{'cached s':>9} {'Mtri/s':>7}")
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['scene']:<26} {r['triangles']:>10,} {r['instances']:>6} {r['lod']:>6.2f} {r['upload']:>9.3f} {r['first']:>12.3f} "
              f"{r['frame']:>8.3f} {r['cached']:>9.3f} {r['triangles'] / r['frame'] / 1e6:>7.2f}")


if __name__ == "__main__":
    main()
