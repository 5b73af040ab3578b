"""What ``foliage preview`` reads of a bake: each method's per-leaf scattered light at the triangle corners, the
LB relighting bases, s_max's data, and whether a bake's sun is the one drawn (``pipeline.preview`` orchestrates)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from foliage_tools.errors import InputError
from foliage_tools.scene.model import MeshPart, Scene

@dataclass(frozen=True)
class MethodData:
    """Where a method's baked scattered light lives, and who writes it."""

    required: str
    """The primvar whose absence means the bake has not run."""
    sources: tuple[str, ...]
    """Primvars holding E_scattered, tried in order."""
    command: str


METHOD_DATA = {
    "lb": MethodData("foliage:lbIndirect", ("foliage:lb:scattered", "foliage:lbIndirect"), "foliage lb"),
    "spp": MethodData("foliage:sppIrradiance", ("foliage:spp:scattered", "foliage:sppIrradiance"), "foliage spp"),
    "smax": MethodData("foliage:smax", ("foliage:smax",), "foliage smax"),
    "reference": MethodData("foliage:ref:scattered", ("foliage:ref:scattered",), "foliage reference"),
}


def corner_values(mesh: MeshPart, values: np.ndarray, interpolation: str, *, where: str) -> np.ndarray:
    """(3T, 3) float32 per-triangle-corner values of a primvar on ``mesh``.

    ``vertex``/``varying`` index the points, ``uniform`` the authored faces,
    ``constant`` is one value; a single channel is repeated as grey.
    """
    v = np.asarray(values, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    if v.shape[1] == 1:
        v = np.repeat(v, 3, axis=1)
    if v.shape[1] != 3:
        raise InputError(f"{where}: expected colours (3 values per element), got {v.shape[1]} per element.")
    n_tri = len(mesh.triangles)
    expected = {"vertex": len(mesh.points), "varying": len(mesh.points), "uniform": mesh.face_count, "constant": 1}
    if interpolation not in expected:
        raise InputError(f"{where}: interpolation {interpolation!r} is not supported by the preview (use vertex or uniform).")
    if len(v) != expected[interpolation]:
        raise InputError(
            f"{where}: {len(v)} values for {interpolation} interpolation, the mesh needs {expected[interpolation]}; re-run the bake."
        )
    if not np.all(np.isfinite(v)):
        raise InputError(f"{where}: holds NaN or infinite values; re-run the bake.")
    if interpolation in ("vertex", "varying"):
        out = v[mesh.triangles]
    elif interpolation == "uniform":
        out = np.repeat(v[mesh.face_of_triangle][:, None, :], 3, axis=1)
    else:
        out = np.broadcast_to(v[0], (n_tri, 3, 3))
    return np.ascontiguousarray(out, dtype=np.float32).reshape(-1, 3)


def load_method_data(path: Path, scene: Scene, methods: tuple[str, ...], warnings: list[str]) -> dict[str, dict[str, np.ndarray]]:
    """Per method (except ``direct``): {leaf mesh path: (3T, 3) E_scattered at each corner}.

    Raises :class:`InputError` naming the command that writes a method's data
    when no leaf mesh has it.
    """
    from foliage_tools.scene.primvars import read_mesh_primvars

    wanted = [m for m in methods if m not in ("direct", "smax")]
    if not wanted:
        return {}
    leaf_meshes = {m.path: m for p in scene.prototypes for m in p.meshes if m.is_leaf}
    if not leaf_meshes:
        raise InputError(f"@{path}@ has no leaf meshes, so it holds no {', '.join(wanted)} data to preview.")
    names = sorted({n for m in wanted for n in (METHOD_DATA[m].required, *METHOD_DATA[m].sources)})
    found = read_mesh_primvars(path, names, list(leaf_meshes))
    out: dict[str, dict[str, np.ndarray]] = {}
    for method in wanted:
        spec = METHOD_DATA[method]
        have_required = found[spec.required]
        if not have_required and not any(found[s] for s in spec.sources):
            raise InputError(
                f"@{path}@ has no {method} data: no leaf mesh has primvars:{spec.required}. Run `{spec.command} {path} -o OUT.usda` "
                f"and preview OUT.usda (or use --method direct)."
            )
        per_mesh = {}
        for mesh_path, mesh in leaf_meshes.items():
            source = next((s for s in spec.sources if mesh_path in found[s]), None)
            if source is None:
                continue
            pv = found[source][mesh_path]
            per_mesh[mesh_path] = corner_values(mesh, pv.values, pv.interpolation, where=f"@{path}@ <{mesh_path}> primvars:{source}")
            if np.any(per_mesh[mesh_path] < 0):
                warnings.append(f"{path}: <{mesh_path}> primvars:{source} has negative irradiance; drawn as 0.")
        if not per_mesh:
            raise InputError(
                f"@{path}@: the {method} bake marker primvars:{spec.required} is there, but no leaf mesh has the scattered irradiance "
                f"({' or '.join('primvars:' + s for s in spec.sources)}) the preview shades with. Re-run `{spec.command}`."
            )
        missing = [p for p in leaf_meshes if p not in per_mesh]
        if missing:
            warnings.append(
                f"{path}: {len(missing)} leaf mesh(es) have no {method} data (e.g. <{missing[0]}>); their scattered light is drawn as 0."
            )
        out[method] = per_mesh
    return out


def load_lb_bases(path: Path, scene: Scene, warnings: list[str]) -> dict[str, np.ndarray]:
    """``{leaf mesh path: (18, 3T, 3) E_scattered of the LB bases B_1..B_18 at each corner}`` (steele2010 sec. 3.1).

    From a ``foliage lb --bases all`` bake: the grids ``lbBase01..18`` hold the total energy
    density u_k of each base; the never-scattered part u_k^un is recomputed exactly
    (``lb.unscattered_energy``) from the leaves voxelized on the same grid and the medium the
    volume records (``foliage:lb:sigmaA/sigmaS/g``), and E_scattered = (u_k - u_k^un) / 2 is
    sampled at the corners (``lighting.lb`` units). Prototypes without base grids (a ``--bases sun``
    bake) are left out: the ``lb`` method then draws ``primvars:foliage:lbIndirect``, which holds
    the baked sun only.
    """
    from foliage_tools.geometry.voxelize import GridSpec, area_per_voxel
    from foliage_tools.lighting import lb as lbm
    from foliage_tools.lighting.lb.collision import Medium, density_from_lad
    from foliage_tools.pipeline.volumes import volume_path
    from foliage_tools.pipeline.lb import sample_trilinear
    from foliage_tools.scene.primvars import read_volume
    from foliage_tools.scene.vdb import on_lattice, read_grid

    out: dict[str, np.ndarray] = {}
    for proto in scene.prototypes:
        leaf_parts = [m for m in proto.meshes if m.is_leaf and len(m.triangles)]
        if not leaf_parts:
            continue
        vol = volume_path(scene, proto)
        names = [f"lbBase{k:02d}" for k in range(1, 19)]
        found, attrs = read_volume(path, vol, names, [f"foliage:lb:{n}" for n in ("sigmaA", "sigmaS", "g")])
        files = [found[n] for n in names]
        if not all(files):
            continue
        medium_attrs = {n: attrs[f"foliage:lb:{n}"] for n in ("sigmaA", "sigmaS", "g")}
        if any(v is None for v in medium_attrs.values()):
            warnings.append(f"{path}: <{vol}> has LB bases but no foliage:lb:sigmaA/sigmaS/g (an older bake): the lb method "
                            "draws the baked sun only; re-run `foliage lb --bases all` to relight.")
            continue
        try:  # a --base-extent leaves bake stores the bases where they are read: put them back on their lattice
            grids = [on_lattice(read_grid(Path(f), f"lbBase{k:02d}")) for k, f in enumerate(files, start=1)]
        except ValueError as exc:
            raise InputError(f"@{path}@: the lbBase grids of <{vol}>: {exc}; re-run `foliage lb --bases all`.") from None
        g0 = grids[0]
        if any(g.values.shape != g0.values.shape or g.origin != g0.origin or g.voxel_size != g0.voxel_size for g in grids):
            raise InputError(f"@{path}@: the lbBase grids of <{vol}> are not on one grid; re-run `foliage lb --bases all`.")
        spec = GridSpec(g0.origin, g0.voxel_size, cast("tuple[int, int, int]", g0.values.shape[:3]))
        rho = density_from_lad(area_per_voxel(proto.triangles(leaves=True), spec) / spec.voxel_volume, spec.voxel_size)
        sigma_a, sigma_s, asym = (tuple(float(x) for x in medium_attrs[n]) for n in ("sigmaA", "sigmaS", "g"))
        medium = Medium(sigma_a, sigma_s, asym)
        problem = lbm.LBProblem(rho, medium, lbm.relighting_boundaries()[1:])
        total = np.stack([g.values for g in grids], axis=3)  # (nx, ny, nz, 18, 3)
        scattered = np.maximum(lbm.scattered_leaf_irradiance(total, lbm.unscattered_energy(problem)), 0.0)
        for m in leaf_parts:
            corners = m.points[m.triangles].reshape(-1, 3)
            out[m.path] = np.ascontiguousarray(np.moveaxis(sample_trilinear(scattered, spec, corners), 1, 0), dtype=np.float32)
    return out


def load_smax_data(path: Path, scene: Scene) -> dict[str, tuple[float, dict[str, np.ndarray]]]:
    """``{prototype path: (τ, {leaf mesh path: (3T, 8) s_max per triangle corner})}`` written by ``foliage smax``.

    The ``smax`` method evaluates Boulanger's model in the vertex shader from these
    (boulanger2008 sec. 5.6), so it follows the preview's sun. Raises
    :class:`InputError` naming ``foliage smax`` when no leaf mesh has
    ``primvars:foliage:smax`` or a baked tree has no ``foliage:tau``.
    """
    from foliage_tools.scene.primvars import read_attribute, read_mesh_primvars

    spec = METHOD_DATA["smax"]
    rerun = f"Run `{spec.command} {path} -o OUT.usda` and preview OUT.usda (or use --method direct)."
    leaf_meshes = {m.path: (k, m) for k, p in enumerate(scene.prototypes) for m in p.meshes if m.is_leaf}
    if not leaf_meshes:
        raise InputError(f"@{path}@ has no leaf meshes, so it holds no smax data to preview.")
    found = read_mesh_primvars(path, [spec.required], list(leaf_meshes))[spec.required]
    if not found:
        raise InputError(f"@{path}@ has no smax data: no leaf mesh has primvars:{spec.required}. {rerun}")
    taus = read_attribute(path, "foliage:tau", [p.path for p in scene.prototypes])
    out: dict[str, tuple[float, dict[str, np.ndarray]]] = {}
    for mesh_path, pv in found.items():
        k, mesh = leaf_meshes[mesh_path]
        proto = scene.prototypes[k]
        where = f"@{path}@ <{mesh_path}> primvars:{spec.required}"
        v = np.asarray(pv.values, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 8:
            raise InputError(f"{where}: expected 8 values per element (elementSize 8, one per direction of eq. (5.28)), "
                             f"got {v.shape[1] if v.ndim == 2 else 1}; re-run `{spec.command}`.")
        expected = {"uniform": mesh.face_count, "vertex": len(mesh.points), "varying": len(mesh.points)}
        if pv.interpolation not in expected or len(v) != expected[pv.interpolation]:
            raise InputError(f"{where}: {len(v)} {pv.interpolation} values, the mesh needs {mesh.face_count} uniform ones; "
                             f"re-run `{spec.command}`.")
        if not np.all(np.isfinite(v)) or np.any(v < 0):
            raise InputError(f"{where}: holds negative, NaN or infinite distances; re-run `{spec.command}`.")
        if pv.interpolation == "uniform":
            corners = np.repeat(v[mesh.face_of_triangle], 3, axis=0)
        else:
            corners = v[mesh.triangles].reshape(-1, 8)
        if proto.path not in out:
            tau: Any = taus[proto.path]  # the attribute's value as USD gives it, checked here
            if tau is None or not (math.isfinite(float(tau)) and float(tau) >= 0):
                raise InputError(f"@{path}@: <{proto.path}> has s_max on its leaves but no valid foliage:tau "
                                 f"(got {tau!r}); the smax bake writes both. {rerun}")
            out[proto.path] = (float(tau), {})
        out[proto.path][1][mesh_path] = corners.astype(np.float32)
    return out


#: The ``foliage:<key>:sunDirection`` a method's bake records (``leafdata.baked_sun_attribute``).
_BAKED_SUN_KEYS = {"lb": "lb", "spp": "spp", "reference": "ref"}

#: Angle (degrees) between the baked and the drawn sun above which the preview warns.
BAKED_SUN_TOLERANCE_DEG = 1.0


def baked_sun_mismatches(path: Path, scene: Scene, methods: tuple[str, ...], sun_direction: np.ndarray) -> list[str]:
    """Warnings for methods whose per-leaf light was baked for another sun than the one drawn.

    Primvar-baked scattered light (lb without relighting bases, spp, the
    reference) holds the sun of its bake only; drawn under another ``--sun`` it
    is silently the wrong light. Each bake records its sun on the prototype
    prim (``foliage:<method>:sunDirection``, prototype frame); bakes without it
    (older layers) are not checked.
    """
    keys = [(m, _BAKED_SUN_KEYS[m]) for m in methods if m in _BAKED_SUN_KEYS]
    if not keys:
        return []
    from foliage_tools.pipeline.stage import first_instance_sun
    from foliage_tools.scene.stored import authored_vectors

    stored = authored_vectors(path, [(proto.path, f"foliage:{key}:sunDirection")
                                     for proto in scene.prototypes for _, key in keys])
    out = []
    for i, proto in enumerate(scene.prototypes):
        drawn = first_instance_sun(scene, i, sun_direction)
        for method, key in keys:
            baked = stored.get((proto.path, f"foliage:{key}:sunDirection"))
            if baked is None:
                continue
            norm = float(np.linalg.norm(baked))
            if not (norm > 0 and np.all(np.isfinite(baked))):
                continue
            angle = math.degrees(math.acos(min(1.0, max(-1.0, float(baked @ drawn) / norm))))
            if angle > BAKED_SUN_TOLERANCE_DEG:
                fix = "leave out --sun to draw the bake's sun, or re-bake with this --sun"
                if method == "lb":
                    fix += " (or `foliage lb --bases all`, which relights for any sun)"
                out.append(f"{path}: the {method} light of <{proto.path}> was baked for a sun {angle:.0f}° away from the one "
                           f"drawn, and is drawn as baked; {fix}.")
    return out
