"""Benchmark the s_max/τ paths of ``foliage smax`` on synthetic crowns.

Usage::

    python benchmarks/bench_smax.py [--leaves 1500 40000 100000] [--repeats 3] [--reference-max 150000]
                                    [--set fast_fine_grid=false ...]

Each crown is boulanger2008's own model (sec. 5.2.1): N leaves with centres
uniform in a ball of radius 1, uniformly random normals and equal areas
A = 2 τ / ρ, so the optical thickness is τ (eq. (5.5), default τ = 2, i.e.
4 optical depths across the crown).

For every N the table gives the wall time of the reference path (the paper's
O(N²) binning, one call) and of the fast path (median of ``--repeats`` calls),
after a warm-up on a tiny crown (numba compilation excluded), the speed-up,
τ of both paths against the true (A/2) ρ, and the fast path's error against
the reference: relative s_max error |s_fast - s_ref| / s_ref over the bins
with s_ref >= 0.05 R (median and 95th percentile; bins nearer the envelope
have s_ref -> 0 and no meaningful relative error), the same error normalised
by the crown radius, |s_fast - s_ref| / R, over all bins (95th percentile),
and the absolute error of the optical depth τ s_max (what the lighting uses)
over all bins. Each path uses its own τ (the fast path's is calibrated on
``fast_tau_leaves`` exactly summed leaves), so the s_max errors include the τ
difference, which the table shows; the relative error of the optical depth
τ s_max over the same bins ("depth rel") is the s_max error with τ taken
out, i.e. what the fast path's sums alone get wrong.

The speed-up divides the reference path's time as implemented
(``envelope._reference_kernel``: the paper's all-pairs sum, numba-parallel
over the leaves) by the fast path's median time, both measured in this run.

Above ``--reference-max`` leaves the reference is not run in full: it is
evaluated exactly on ``--probe-leaves`` random leaves (all N partners each),
its time is scaled by N / probes and marked "est.", and the errors are over
those probe leaves (with the probes' own τ).
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numba

from foliage_tools.lighting import envelope
from foliage_tools.lighting.envelope import EnvelopeParams, solve


def uniform_ball(n: int, tau: float, rng: np.random.Generator):
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    centres = d * rng.uniform(size=(n, 1)) ** (1.0 / 3.0)
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return centres, normals, np.full(n, 2.0 * tau / (n / (4.0 / 3.0 * math.pi)))


def errors(s_fast, s_ref, tau_fast, tau_ref) -> dict:
    big = s_ref >= 0.05
    rel = np.abs(s_fast[big] - s_ref[big]) / s_ref[big]
    d_fast, d_ref = tau_fast * s_fast.astype(float), tau_ref * s_ref.astype(float)
    ddepth = np.abs(d_fast - d_ref)
    drel = ddepth[big] / d_ref[big]
    return {
        "rel_med": float(np.median(rel)),
        "rel_p95": float(np.percentile(rel, 95)),
        "crown_p95": float(np.percentile(np.abs(s_fast.astype(float) - s_ref.astype(float)), 95)),  # R = 1
        "drel_med": float(np.median(drel)),
        "drel_p95": float(np.percentile(drel, 95)),
        "depth_med": float(np.median(ddepth)),
        "depth_p95": float(np.percentile(ddepth, 95)),
    }


def reference_on_probes(c, n, a, probes, params):
    """Exact reference s_max on some leaves: the same pair sums as the reference path, for those leaves only."""
    frame = envelope.sample_frame((0, 0, 1))
    x, nl = np.ascontiguousarray(c @ frame.T), np.ascontiguousarray(n @ frame.T)
    depth, far, s1 = envelope._reference_depths(x, nl, a, probes, params.max_occlusion)
    tau = envelope._estimate_tau(depth, far, s1, params.tau_estimator)
    return (depth / tau).astype(np.float32), tau


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--leaves", type=int, nargs="+", default=[1500, 40_000, 100_000])
    ap.add_argument("--tau", type=float, default=2.0, help="optical thickness (A/2) ρ of the crowns, 1/radius")
    ap.add_argument("--repeats", type=int, default=3, help="timed fast-path calls per N (median reported)")
    ap.add_argument("--reference-max", type=int, default=150_000, help="largest N for a full reference run")
    ap.add_argument("--probe-leaves", type=int, default=2000, help="leaves of the reference estimate above --reference-max")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--set", nargs="*", default=[], metavar="KEY=VALUE",
        help="fast-path EnvelopeParams fields, e.g. --set fast_fine_grid=false fast_split_cells=2.7",
    )
    args = ap.parse_args(argv)
    fast_fields = {}
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep:
            ap.error(f"--set takes KEY=VALUE, got {item!r}")
        low = value.lower()
        fast_fields[key] = low == "true" if low in ("true", "false") else (int(value) if value.lstrip("-").isdigit() else float(value))
    if args.repeats < 1 or min(args.leaves) < 2:
        ap.error("--repeats must be >= 1 and --leaves >= 2")

    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    print(
        f"numba {numba.__version__}, {numba.get_num_threads()} thread(s), {os.cpu_count()} CPU(s), "
        f"load average before: {load[0]:.2f}"
    )
    rng = np.random.default_rng(args.seed)
    warm = uniform_ball(200, args.tau, rng)
    solve(*warm, params=EnvelopeParams(path="reference"))
    fast_params = EnvelopeParams(path="fast", **fast_fields)
    solve(*warm, params=fast_params)
    if fast_fields:
        print("fast path with " + ", ".join(f"{k}={v!r}" for k, v in fast_fields.items()))

    ref_params = EnvelopeParams(path="reference")
    header = (
        f"{'leaves':>8} | {'reference s':>13} | {'fast s':>8} | {'speed-up':>8} | {'tau ref':>7} | {'tau fast':>8} |"
        f" {'tau true':>8} | {'s_max rel err med':>17} | {'p95':>6} | {'|ds|/R p95':>10} | {'depth rel med':>13} | {'p95':>6} | {'|d depth| med':>13} | {'p95':>6} | fast grid"
    )
    print(header)
    print("-" * len(header))
    for n_leaves in args.leaves:
        c, n, a = uniform_ball(n_leaves, args.tau, rng)
        times, fast = [], None
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            fast = solve(c, n, a, params=fast_params)
            times.append(time.perf_counter() - t0)
        t_fast = statistics.median(times)
        if n_leaves <= args.reference_max:
            t0 = time.perf_counter()
            ref = solve(c, n, a, params=ref_params)
            t_ref = time.perf_counter() - t0
            err = errors(fast.smax, ref.smax, fast.tau, ref.tau)
            t_ref_text, tau_ref = f"{t_ref:13.3f}", ref.tau
        else:
            probes = np.sort(rng.choice(n_leaves, size=args.probe_leaves, replace=False)).astype(np.int64)
            t0 = time.perf_counter()
            s_probe, tau_ref = reference_on_probes(c, n, a, probes, ref_params)
            t_ref = (time.perf_counter() - t0) * n_leaves / args.probe_leaves
            err = errors(fast.smax[probes], s_probe, fast.tau, tau_ref)
            t_ref_text = f"{t_ref:8.1f} est."
        print(
            f"{n_leaves:8d} | {t_ref_text} | {t_fast:8.4f} | {t_ref / t_fast:7.0f}x | {tau_ref:7.4f} | {fast.tau:8.4f} |"
            f" {args.tau:8.4f} | {100 * err['rel_med']:16.2f}% | {100 * err['rel_p95']:5.1f}% | {100 * err['crown_p95']:9.2f}% |"
            f" {100 * err['drel_med']:12.2f}% | {100 * err['drel_p95']:5.1f}% |"
            f" {err['depth_med']:13.4f} | {err['depth_p95']:6.3f} | {fast.stats['grid']}"
            + (f" + fine {fast.stats['fine_grid']}" if "fine_grid" in fast.stats else "")
            + f", {fast.stats['near_pairs']} near pairs"
        )
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    print(f"load average after: {load[0]:.2f} (other processes share the CPUs; timings vary with it)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
