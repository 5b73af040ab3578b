"""``foliage smax``: per-leaf envelope distances s_max, tree optical thickness τ and Boulanger's lighting.

boulanger2008 chapter 5: s_max(P, ω_j) for the 8 directions of eq. (5.28),
τ (eq. 5.5 estimated as in sec. 5.6), then per-leaf E_direct and E_scattered
(eqs. 5.7–5.8, 5.11, 5.24–5.26, 5.33) for the scene's sun. By default the
scattered light's first order is the leaves' exact direct light scattered once
and marched through a voxel medium of the leaves (``--scatter march``,
:mod:`foliage_tools.lighting.first_order`, as ``spp`` and ``lb`` take it), and
the later orders are counted by the envelope's recollision probability
(:func:`foliage_tools.lighting.envelope.boulanger.higher_orders`); ``--scatter leaves``
lights the thesis' one-bounce scatterers by the leaves' exact lit fractions
instead, and ``paper`` is the thesis' eq. (5.24).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import cast

import numpy as np

from foliage_tools import __version__
from foliage_tools.geometry.sun import Sun, to_prototype_space
from foliage_tools.lighting import envelope
from foliage_tools.lighting.envelope import boulanger, scatterer_sun
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.pipeline.forest import forest_light
from foliage_tools.pipeline.instances import bake_instance_edits, from_prototypes
from foliage_tools.pipeline.world import bake_world, prototype_means
from foliage_tools.pipeline.direct import DirectBake, DirectChoice, bake_direct
from foliage_tools.pipeline.first_order import marched_once
from foliage_tools.pipeline.leafdata import baked_sun_attribute, leaf_primvar_edits, native_instance_warning
from foliage_tools.pipeline.report import Progress, Report
from foliage_tools.pipeline.stats import SmaxPrototypeStats, SmaxStats, sun_stats
from foliage_tools.pipeline.stage import bake_layer, sun_in_prototype
from foliage_tools.scene.model import Scene
from foliage_tools.scene.schemas import ENVELOPE_API
from foliage_tools.scene.write import AttributeEdit, LayerEdits

log = logging.getLogger(__name__)

PATHS = ("auto", "reference", "fast")
#: ``--scatter``: ``march`` takes the first order from the leaves' exact direct light marched through a voxel medium
#: (lighting.first_order) and the later orders from the envelope's recollision probability (boulanger.higher_orders);
#: ``leaves`` lights the thesis' one-bounce scatterers by the leaves' exact lit fractions and adds the same higher
#: orders (lighting.scatterer_sun); ``paper`` is boulanger2008's one bounce, eq. (5.24).
SCATTER = ("march", "leaves", "paper")


@dataclass(frozen=True)
class SmaxParams:
    """What ``foliage smax`` computes."""

    optics: LeafOptics
    """Leaf reflectance/transmittance (``--leaf-optics``)."""
    sun: tuple[float, float] | None = None
    """``--sun`` azimuth, elevation in degrees; None: the stage's sun or the default."""
    path: str = "auto"
    """``reference`` (the paper's O(N²) binning), ``fast`` (near sums + FFT far field) or ``auto``
    (reference below envelope.EnvelopeParams.auto_threshold leaves)."""
    direct: DirectChoice = DirectChoice()
    """``--direct``: what ``primvars:foliage:smax:direct`` holds (exact shadow rays by default, or eq. 5.7's own)."""
    scatter: str = "march"
    """``--scatter``: see :data:`SCATTER`."""

    def __post_init__(self) -> None:
        from foliage_tools.errors import UsageError

        if self.path not in PATHS:
            raise UsageError(f"--path must be one of {', '.join(PATHS)}, got {self.path!r}.")
        if self.scatter not in SCATTER:
            raise UsageError(f"--scatter must be one of {', '.join(SCATTER)}, got {self.scatter!r}.")

    @property
    def needs_rays(self) -> bool:
        """Whether the bake traces the exact direct light (for its E_direct or for its scattered light)."""
        return self.direct.mode == "rays" or self.scatter in ("leaves", "march")


@dataclass(frozen=True)
class SmaxBake:
    """One prototype's envelope and lighting."""

    index: int
    envelope: envelope.EnvelopeResult
    lighting: boulanger.LightingResult
    scatter_seconds: float = 0.0
    """Wall time of the scatterers' sun (lighting.scatterer_sun; 0 with ``--scatter paper``)."""

    @property
    def seconds(self) -> float:
        """Envelope, scatterers' sun and lighting of this prototype."""
        return self.envelope.seconds + self.scatter_seconds + self.lighting.seconds


def sky_radiance(scene: Scene) -> tuple[float, float, float]:
    """The dome light's intensity × colour as sky radiance per unit sun irradiance (0 without a dome)."""
    domes = [light for light in scene.lights if light.kind == "dome"]
    return cast("tuple[float, float, float]", tuple(float(domes[0].intensity * c) for c in domes[0].color)) if domes else (0.0, 0.0, 0.0)


def lit_fractions(scene: Scene, exact: DirectBake) -> list[np.ndarray]:
    """Per prototype, each leaf's exact transmission toward the sun (its lit fraction), the mean over its instances."""
    counts = [p.leaves.count for p in scene.prototypes]
    return prototype_means(exact.world, exact.result.lit_fraction, len(counts), counts)


def bake_smax(scene: Scene, sun: Sun, params: SmaxParams, warnings: list[str], progress: Progress,
              exact: DirectBake | None = None) -> list[SmaxBake]:
    """Envelope and lighting of every prototype with leaves (pure numerics on the scene's arrays).

    ``exact``: the exact direct light of this scene and sun, traced here when ``--scatter leaves`` needs it and
    none is given."""
    sky = sky_radiance(scene)
    lit = None
    if params.scatter in ("leaves", "march"):
        exact = exact if exact is not None else bake_direct(scene, sun, params.direct, progress)
        lit = lit_fractions(scene, exact)
    baked = scene.leafy_prototypes()
    progress.step(f"s_max for {len(baked)} prototype(s)", total=len(baked))
    out = []
    for i, proto in baked:
        sun_local = sun_in_prototype(scene, i, sun, warnings)
        insts = scene.instances_of(i)
        up_local = to_prototype_space(scene.up, insts[0].transform) if insts else scene.up
        env = envelope.solve(
            proto.leaves.centers, proto.leaves.normals, proto.leaves.areas, up=up_local, params=envelope.EnvelopeParams(path=params.path)
        )
        t0 = time.perf_counter()
        # march replaces the one bounce, so its scatterers need no sun; it keeps the higher orders' p (all_orders)
        t_bar = None if lit is None or params.scatter != "leaves" else scatterer_sun.scatterer_transmission(
            proto.leaves.centers, np.clip(lit[i], 0.0, 1.0), env.tau, up=up_local,
            leaf_size=float(np.sqrt(np.mean(proto.leaves.areas))))
        scatter_seconds = time.perf_counter() - t0
        light = boulanger.solve(
            proto.leaves.normals,
            env.smax,
            env.tau,
            up=up_local,
            params=boulanger.BoulangerParams(
                sun_direction=tuple(sun_local),
                reflectance=tuple(params.optics.reflectance),
                transmittance=tuple(params.optics.transmittance),
                sky_radiance=sky,
            ),
            scatterer_sun=t_bar,
            all_orders=lit is not None,
        )
        progress.advance()
        log.info("smax <%s>: %d leaves, %s path, tau %.3g, scatterers %.2f s", proto.path, proto.leaves.count,
                 params.path, float(env.tau), scatter_seconds)
        out.append(SmaxBake(i, env, light, scatter_seconds))
    if params.scatter == "march" and out:
        assert exact is not None  # traced above for march
        out = _marched(scene, sun, params.optics, out, exact, progress)
    return out


def _marched(scene: Scene, sun: Sun, optics: LeafOptics, bakes: list[SmaxBake], exact: DirectBake,
             progress: Progress) -> list[SmaxBake]:
    """``bakes`` with E_scattered = the marched first order (lighting.first_order, the mean over a prototype's
    instances) times 1 / (1 - ω p), the later orders at the envelope's recollision probability p
    (boulanger.higher_orders, the factor ``--scatter leaves`` applies to its one bounce)."""
    t0 = time.perf_counter()
    once = marched_once(scene, sun, optics, exact, progress, "s_max")
    counts = [p.leaves.count for p in scene.prototypes]
    means = prototype_means(exact.world, once, len(counts), counts)
    albedo = np.asarray(optics.reflectance, dtype=np.float64) + np.asarray(optics.transmittance, dtype=np.float64)
    seconds = time.perf_counter() - t0
    out = []
    for b in bakes:
        light = b.lighting
        p = light.stats["recollision_probability"]
        scattered = (means[b.index] * boulanger.higher_orders(albedo, float(p))).astype(np.float32)
        old = np.asarray(light.e_scattered, dtype=np.float64)
        # the front face keeps the share the envelope model gives it (the march sums the two faces)
        share = np.divide(np.asarray(light.e_scattered_front, dtype=np.float64), old, out=np.full(old.shape, 0.5),
                          where=old > 0)
        light = replace(light, e_scattered=scattered, e_scattered_front=(scattered * share).astype(np.float32),
                        stats={**light.stats, "first_order": "march"})
        out.append(SmaxBake(b.index, b.envelope, light, b.scatter_seconds + seconds / len(bakes)))
    return out


def smax_layer(scene: Scene, sun: Sun, report: Report, progress: Progress, *, out: Path,
             params: SmaxParams) -> tuple[LayerEdits, SmaxStats]:
    """``foliage smax``'s computation and layer (``pipeline.stage.bake_layer`` reads before and writes after)."""
    edits = LayerEdits()
    protos: list[SmaxPrototypeStats] = []
    traced = bake_direct(scene, sun, params.direct, progress) if params.needs_rays else None
    bakes = bake_smax(scene, sun, params, report.warnings, progress, exact=traced)
    exact = traced if params.direct.mode == "rays" else None
    for bake in bakes:
        proto, env, light = scene.prototypes[bake.index], bake.envelope, bake.lighting
        e_direct = exact.per_prototype[bake.index] if exact else light.e_direct
        if not proto.editable:
            report.warnings.append(native_instance_warning(proto, "s_max primvars"))
        edits.primvars += leaf_primvar_edits(proto, "foliage:smax", env.smax, type="float", element_size=8)
        edits.primvars += leaf_primvar_edits(proto, "foliage:attenuation", env.attenuation, type="float", element_size=8)
        # the same values one direction per primvar (foliage:smax0..7, foliage:attenuation0..7): DCCs that import
        # primvars as mesh attributes take one value per element (Blender 5.0 turned elementSize 8 into zeros)
        for k in range(env.smax.shape[1]):
            edits.primvars += leaf_primvar_edits(proto, f"foliage:smax{k}", env.smax[:, k], type="float")
            edits.primvars += leaf_primvar_edits(proto, f"foliage:attenuation{k}", env.attenuation[:, k], type="float")
        edits.primvars += leaf_primvar_edits(proto, "foliage:smax:direct", e_direct, type="color3f")
        edits.primvars += leaf_primvar_edits(proto, "foliage:smax:scattered", light.e_scattered, type="color3f")
        edits.attributes += baked_sun_attribute(scene, bake.index, "smax", sun.direction)
        if proto.editable:
            edits.attributes.append(
                AttributeEdit(
                    prim=proto.path,
                    api=ENVELOPE_API,
                    values={
                        "foliage:tau": (float(env.tau), "Float"),
                        "foliage:smax:path": (env.path, "Token"),
                        "foliage:smax:scatter": (params.scatter, "Token"),
                        "foliage:smax:seconds": (float(bake.seconds), "Float"),
                        "foliage:smax:version": (__version__, "String"),
                    },
                )
            )
        protos.append(
            {
                "path": proto.path,
                "leaves": proto.leaves.count,
                "tau": float(env.tau),
                "path_used": env.path,
                "smax_mean": float(np.mean(env.smax)),
                "e_direct_mean": np.mean(e_direct, axis=0).tolist(),
                "e_direct_volume_mean": np.mean(light.e_direct, axis=0).tolist(),
                "e_scattered_mean": np.mean(light.e_scattered, axis=0).tolist(),
                "seconds": float(bake.seconds),
                "scatter": params.scatter,
                "recollision_probability": light.stats["recollision_probability"],
            }
        )
    world = traced.world if traced else bake_world(scene)
    forest = forest_light(scene, sun, params.optics, progress=progress)  # the neighbours' scattered light
    pv, at = bake_instance_edits(
        scene, "smax", world,
        exact.result.e_direct if exact else from_prototypes(world, {b.index: b.lighting.e_direct for b in bakes}),
        from_prototypes(world, {b.index: b.lighting.e_scattered for b in bakes}), forest=forest, exact_direct=exact)
    edits.primvars += pv
    edits.attributes += at
    stats: SmaxStats = {
        "leaves": int(sum(p["leaves"] for p in protos)),
        "tau": protos[0]["tau"] if len(protos) == 1 else [p["tau"] for p in protos],
        "path": protos[0]["path_used"] if len(protos) == 1 else [p["path_used"] for p in protos],
        "sun": sun_stats(sun),
        "optics": params.optics.as_dict(),
        "version": __version__,
        "prototypes": protos,
        "direct": exact.stats() if exact else {"mode": "volume"},
        "forest": forest.stats() if forest is not None else None,
    }
    return edits, stats


def run_smax(path: Path, out: Path, params: SmaxParams, *, progress: Progress | None = None) -> Report[SmaxStats]:
    return bake_layer("smax", path, out, params.sun, progress,
                      partial(smax_layer, out=out, params=params))
