"""The entry point :func:`solve`: checks the leaves, takes the reference or the fast path, and turns the bins'
optical depths into s_max, attenuation and τ."""

from __future__ import annotations

import time

import numpy as np

from foliage_tools.lighting.envelope.directions import sample_directions, sample_frame
from foliage_tools.lighting.envelope.fast import _fast_depths
from foliage_tools.lighting.envelope.params import EnvelopeParams, EnvelopeResult
from foliage_tools.lighting.envelope.reference import _reference_depths
from foliage_tools.lighting.envelope.tau import _estimate_tau, _tau_probes


def _check_leaves(centres, normals, areas) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    c = np.ascontiguousarray(centres, dtype=np.float64)
    n = np.ascontiguousarray(normals, dtype=np.float64)
    a = np.ascontiguousarray(areas, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"leaf centres must have shape (L, 3), got {c.shape}")
    if n.shape != c.shape:
        raise ValueError(f"leaf normals must have the shape of the centres {c.shape}, got {n.shape}")
    if a.shape != (c.shape[0],):
        raise ValueError(f"leaf areas must have shape ({c.shape[0]},), got {a.shape}")
    for name, arr in (("centres", c), ("normals", n), ("areas", a)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"leaf {name} contain NaN or infinite values")
    if np.any(a < 0):
        raise ValueError("leaf areas must be >= 0")
    norm = np.linalg.norm(n, axis=1)
    if np.any(np.abs(norm - 1.0) > 1e-3):
        raise ValueError("leaf normals must be unit vectors (|n| - 1 > 1e-3 found)")
    return c, n / norm[:, None], a


def solve(centres, normals, areas, *, up=(0.0, 0.0, 1.0), params: EnvelopeParams | None = None) -> EnvelopeResult:
    """s_max(P, ω_j) for every leaf and the 8 directions, and the tree's τ.

    Parameters
    ----------
    centres : (L, 3) float, stage units
        Leaf centres P.
    normals : (L, 3) float
        Unit leaf normals (the sign does not matter here).
    areas : (L,) float, stage units²
        One-sided leaf areas.
    up : (3,) float
        The stage's up axis; fixes the sample directions (:func:`sample_directions`).
    params : EnvelopeParams

    Returns
    -------
    EnvelopeResult
        ``smax`` and ``attenuation`` (L, 8) float32, ``tau`` float, all finite.
        On the reference path a bin holding no other leaf gets s_max = 0 and
        attenuation 1 (the fast path's grid blurs the bin planes, so such a bin
        may get a small value); a tree with fewer than two leaves gets τ = 0.
    """
    t0 = time.perf_counter()
    params = params or EnvelopeParams()
    c, n, a = _check_leaves(centres, normals, areas)
    frame = sample_frame(up)
    dirs = sample_directions(up)
    # positions and normals in the sample frame: the bin of d is its octant there
    x = np.ascontiguousarray(c @ frame.T)
    nl = np.ascontiguousarray(n @ frame.T)
    n_leaves = c.shape[0]
    path = params.path
    if path == "auto":
        path = "reference" if n_leaves < params.auto_threshold else "fast"

    stats: dict = {"leaves": n_leaves, "tau_estimator": params.tau_estimator}
    if path == "reference":
        depth, far, s1 = _reference_depths(x, nl, a, np.arange(n_leaves, dtype=np.int64), params.max_occlusion)
        tau = _estimate_tau(depth, far, s1, params.tau_estimator)
    else:
        depth, tau_depth, s1, fast_stats = _fast_depths(x, nl, a, params)
        stats.update(fast_stats)
        probes = _tau_probes(n_leaves, params.fast_tau_leaves, params.seed)
        pdepth, pfar, ps1 = _reference_depths(x, nl, a, probes, params.max_occlusion)
        stats["tau_sample_leaves"] = int(probes.shape[0])
        if params.tau_estimator == "moments":
            # τ from all leaves' fast sums, times a correction measured on the
            # probes (exact / fast on the same leaves): removes the fast sums'
            # bias (the grid blurs the bin planes, which leaks a little light
            # path into the outward bins of leaves at the envelope)
            tau = _estimate_tau(tau_depth, None, s1, "moments")
            fast_on_probes = _estimate_tau(tau_depth[probes], None, s1[probes], "moments")
            if fast_on_probes > 0.0:
                correction = _estimate_tau(pdepth, None, ps1, "moments") / fast_on_probes
                stats["tau_correction"] = float(correction)
                tau *= correction
        else:
            # s_far (a maximum) has no far-field form: the probes alone
            tau = _estimate_tau(pdepth, pfar, ps1, "farthest")

    if tau > 0.0:
        # (the clip only matters for absurd inputs: lengths beyond float32's range)
        smax = np.minimum(depth / tau, float(np.finfo(np.float32).max)).astype(np.float32)
    else:
        smax = np.zeros_like(depth, dtype=np.float32)
    attenuation = np.exp(-tau * smax.astype(np.float64)).astype(np.float32)
    stats["empty_bins"] = int(np.count_nonzero(depth == 0.0))
    return EnvelopeResult(
        smax=smax,
        attenuation=attenuation,
        tau=float(tau),
        directions=dirs,
        path=path,
        seconds=time.perf_counter() - t0,
        stats=stats,
    )
