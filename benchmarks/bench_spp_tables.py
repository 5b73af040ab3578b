"""Reproduce shinya2013 Tables 1 and 2: SPP (S.) and refined (R.) radiance vs the exact slab solution.

Usage::

    python benchmarks/bench_spp_tables.py [--quick] [--table2-g 0.0]

Setup (the paper gives only "averaged over a number of directions and depth
values, normalized by the total power"; the choices here are ours):

* exact reference: :func:`foliage_tools.lighting.plane_parallel.solve_slab`
  (discrete ordinates, 16 streams per hemisphere), Henyey-Greenstein phase,
  σt = 1, beam of unit irradiance;
* incident cosines μ0 = 1.0, 0.8, 0.6, 0.4, 0.2 (``--quick``: 1.0, 0.5);
* depths t = 0, 0.1 w', ..., w' with w' = min(w, 10) (11 depths, both faces
  included; for w = inf, t = 0 .. 10);
* directions: Gauss-Legendre in the cosine, 16 per hemisphere, × 16 azimuths on
  [0, π] (the field is symmetric in azimuth); the beam (a delta) is left out of
  the radiance difference;
* **error (the one compared with the paper)**:
  ``sqrt(mean over (μ0, t) of (1/4π)∫ (I - I_exact)² dΩ) / mean over (μ0, t) of P``,
  with P = ∫ I_exact dΩ + exp(-t/μ0) the total (diffuse + direct) power at that
  depth. This is "RMS difference normalised by the total power" read
  literally: an RMS *radiance* divided by a *power* (a radiance times 4π), so it
  is the relative error divided by 4π. Low albedos get low errors because the
  direct beam dominates P, as the paper remarks;
* second column ``rel``: the dimensionless relative RMS of the diffuse
  radiance, sqrt(Σ ∫(I - I_exact)² dΩ / Σ ∫ I_exact² dΩ) over the same samples
  (the error measure of DESIGN.md sec. 3), for a plain reading of the accuracy;
* "total" rows: the root mean square of the five albedo rows.

Prints the tables beside the paper's values, then the evaluation speed of the
SPP field and of the refinement (numba compilation excluded).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from foliage_tools.lighting import spp
from foliage_tools.lighting.phase import hg_phase
from foliage_tools.lighting.plane_parallel import solve_slab

ALBEDOS = (0.5, 0.7, 0.9, 0.95, 0.99)
# shinya2013 Table 1: (S., R.) per albedo for g = 0.0, 0.5, -0.5, then the "total" row
PAPER_T1 = {
    0.0: [(2.7, 0.3), (1.9, 0.5), (2.1, 1.2), (2.9, 1.7), (4.5, 3.9), (2.8, 1.7)],
    0.5: [(1.3, 0.3), (2.1, 0.7), (3.4, 1.7), (4.1, 2.7), (5.5, 5.8), (3.3, 2.5)],
    -0.5: [(1.2, 0.2), (1.8, 0.4), (2.7, 1.3), (3.4, 2.0), (5.0, 4.7), (2.9, 2.1)],
}
# shinya2013 Table 2 (phase function and S./R. not stated; "other conditions as Table 1")
PAPER_T2 = {
    math.inf: [0.3, 0.7, 1.7, 2.3, 4.0, 2.3],
    16.0: [0.3, 0.7, 1.7, 2.2, 4.6, 2.5],
    10.0: [0.3, 0.7, 1.6, 2.1, 4.6, 2.4],
    5.0: [0.4, 0.8, 1.6, 2.6, 4.4, 2.5],
}


def direction_quadrature(n_mu: int = 16, n_phi: int = 16):
    x, w = np.polynomial.legendre.leggauss(n_mu)
    mu_h, w_h = 0.5 * (x + 1.0), 0.5 * w
    mu = np.concatenate([mu_h, -mu_h])  # cosine to the inward normal: > 0 going deeper
    w_mu = np.concatenate([w_h, w_h])
    phi = (np.arange(n_phi) + 0.5) * math.pi / n_phi
    m, p = np.meshgrid(mu, phi, indexing="ij")
    wd = w_mu[:, None] * np.full(n_phi, 2.0 * math.pi / n_phi)[None, :]  # Σ = 4π
    return m, p, wd


def case_errors(g: float, omega: float, tau: float, mu0s, quad):
    """Accumulated squared differences and powers for the SPP (S.) and refined (R.) radiance."""
    m, p, wd = quad
    ph = hg_phase(g)
    acc = {"S": [], "R": []}
    ref2, power = [], []
    for mu0 in mu0s:
        span = min(tau, 10.0)
        ts = np.linspace(0.0, span, 11)
        sol = solve_slab(tau=tau, omega=omega, mu0=mu0, phase=ph, depths=ts)
        exact = sol.radiance(ts[:, None, None], -m[None], p[None])  # solve_slab's μ is from the upward vertical
        big_u = tau / mu0
        field = spp.spp_field(ts / mu0, big_u, albedo=omega, forward_fraction=spp.forward_fraction(ph, mu0))
        plain = np.where(m[None] > 0, field.down[:, None, None], field.up[:, None, None]) / (2.0 * math.pi)
        refined = spp.refined_radiance(ts[:, None, None] / mu0, big_u, mu0=mu0, mu=m[None], phi=p[None], albedo=omega, phase=ph)
        acc["S"].append(np.sum((plain - exact) ** 2 * wd, axis=(1, 2)))
        acc["R"].append(np.sum((refined - exact) ** 2 * wd, axis=(1, 2)))
        ref2.append(np.sum(exact**2 * wd, axis=(1, 2)))
        power.append(np.exp(-ts / mu0) + np.sum(exact * wd, axis=(1, 2)))
    p_mean = float(np.mean(np.concatenate(power)))
    r2 = float(np.sum(np.concatenate(ref2)))
    out = {}
    for key, d2 in acc.items():
        d2 = np.concatenate(d2)
        out[key] = (
            100.0 * math.sqrt(float(np.mean(d2)) / (4.0 * math.pi)) / p_mean,  # paper's reading
            100.0 * math.sqrt(float(np.sum(d2)) / r2),  # relative RMS
        )
    return out


def rms(values):
    return math.sqrt(sum(v * v for v in values) / len(values))


def table1(mu0s, quad):
    print("Table 1: RMS errors (%) of SPP (S.) and refined (R.), thickness 10/σt, HG phase")
    print("  error = paper's reading (see docstring); rel = relative RMS of the diffuse radiance; paper = shinya2013")
    for g in (0.0, 0.5, -0.5):
        print(f"\n  g = {g:+.1f}")
        print(f"  {'albedo':>7} | {'S. error':>8} {'paper':>6} {'rel':>6} | {'R. error':>8} {'paper':>6} {'rel':>6}")
        rows = []
        for i, omega in enumerate(ALBEDOS):
            e = case_errors(g, omega, 10.0, mu0s, quad)
            ps, pr = PAPER_T1[g][i]
            rows.append(e)
            print(f"  {omega:>7.2f} | {e['S'][0]:8.2f} {ps:6.1f} {e['S'][1]:6.1f} | {e['R'][0]:8.2f} {pr:6.1f} {e['R'][1]:6.1f}")
        ps, pr = PAPER_T1[g][-1]
        ts = [rms([r[k][j] for r in rows]) for k in ("S", "R") for j in (0, 1)]
        print(f"  {'total':>7} | {ts[0]:8.2f} {ps:6.1f} {ts[1]:6.1f} | {ts[2]:8.2f} {pr:6.1f} {ts[3]:6.1f}")


def table2(mu0s, quad, g: float):
    print(f"\nTable 2: RMS errors (%) vs thickness w (σt = 1), g = {g:+.1f}; paper values (method not stated, likely R.)")
    widths = (math.inf, 16.0, 10.0, 5.0)
    print(f"  {'':>7} | " + " | ".join(f"{'w = ' + w:^18}" for w in ("inf", "16", "10", "5")))
    print(f"  {'albedo':>7} | " + " | ".join(f"{'R.':>6} {'S.':>5} {'paper':>5}" for _ in widths))
    cols = {w: [] for w in widths}
    for i, omega in enumerate(ALBEDOS):
        cells = []
        for w in widths:
            e = case_errors(g, omega, w, mu0s, quad)
            cols[w].append(e)
            cells.append(f"{e['R'][0]:6.2f} {e['S'][0]:5.2f} {PAPER_T2[w][i]:5.1f}")
        print(f"  {omega:>7.2f} | " + " | ".join(cells))
    cells = []
    for w in widths:
        r = rms([e["R"][0] for e in cols[w]])
        s = rms([e["S"][0] for e in cols[w]])
        cells.append(f"{r:6.2f} {s:5.2f} {PAPER_T2[w][-1]:5.1f}")
    print(f"  {'total':>7} | " + " | ".join(cells))


def speed():
    rng = np.random.default_rng(0)
    n = 1_000_000
    big_u = rng.uniform(0.0, 20.0, n)
    u = big_u * rng.uniform(0.0, 1.0, n)
    om = rng.uniform(0.0, 1.0, n)
    t = rng.uniform(0.3, 0.9, n)
    spp.spp_field(u[:10], big_u[:10], albedo=om[:10], forward_fraction=t[:10])  # compile
    t0 = time.perf_counter()
    spp.spp_field(u, big_u, albedo=om, forward_fraction=t)
    dt = time.perf_counter() - t0
    mu = rng.uniform(-1.0, 1.0, n)
    mu[mu == 0.0] = 0.5
    spp.refined_parts(u[:10], big_u[:10], mu0=0.7, mu=mu[:10], albedo=om[:10], forward_fraction_sun=t[:10], forward_fraction_ray=t[:10])
    t0 = time.perf_counter()
    spp.refined_parts(u, big_u, mu0=0.7, mu=mu, albedo=om, forward_fraction_sun=t, forward_fraction_ray=t)
    dr = time.perf_counter() - t0
    print(f"\nspeed: SPP field {n / dt / 1e6:.1f} M points/s, refinement {n / dr / 1e6:.2f} M (point, direction)/s (1 thread)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="2 incident directions and 8 azimuths instead of 5 and 16")
    ap.add_argument("--table2-g", type=float, default=0.0, help="HG asymmetry for Table 2 (the paper does not say)")
    args = ap.parse_args(argv)
    mu0s = (1.0, 0.5) if args.quick else (1.0, 0.8, 0.6, 0.4, 0.2)
    quad = direction_quadrature(16, 8 if args.quick else 16)
    t0 = time.perf_counter()
    print(f"incident cosines μ0 = {mu0s}; depths t = 0 .. min(w, 10) in 10 steps; 32 x {quad[0].shape[1]} directions\n")
    table1(mu0s, quad)
    table2(mu0s, quad, args.table2_g)
    speed()
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
