"""Entry points: :func:`solve_slab` (collimated beam) and :func:`solve_slab_diffuse` (isotropic sky).

Input checks, the double-Gauss quadrature, the exact tau = 0 case, and the
fluxes, depth profiles and absorptance from the Fourier order 0 solution; the
result is a :class:`~foliage_tools.lighting.plane_parallel.solution.SlabSolution`.
"""

from __future__ import annotations

import math

import numpy as np

from foliage_tools.lighting.phase import PhaseFunction, _as_real
from foliage_tools.lighting.plane_parallel.constants import MAX_STREAMS
from foliage_tools.lighting.plane_parallel.eigen import _eigen, _Setup
from foliage_tools.lighting.plane_parallel.modes import _solve_mode
from foliage_tools.lighting.plane_parallel.solution import _Field, SlabSolution
from foliage_tools.lighting.plane_parallel.special import _decay


# --------------------------------------------------------------------------
# public entry points
# --------------------------------------------------------------------------


_real = _as_real  # one checker for both modules (lighting.phase)


def _validate(tau, omega, phase, n_streams, depths, floor_albedo):
    tau = _real("tau (optical thickness)", tau)
    if tau < 0.0:
        raise ValueError(
            f"tau (optical thickness) must be >= 0 (inf for a semi-infinite slab), got {tau}"
        )
    omega = _real("omega (single-scattering albedo)", omega)
    if not 0.0 <= omega <= 1.0:
        raise ValueError(
            f"omega (single-scattering albedo) must be in [0, 1], got {omega}"
        )
    if not isinstance(phase, PhaseFunction):
        raise ValueError(  # noqa: TRY004 (project convention: bad inputs -> ValueError)
            "phase must be a PhaseFunction (e.g. hg_phase(g) or canopy_bilambertian_phase(...)), "
            f"got {type(phase).__name__}"
        )
    if isinstance(n_streams, bool) or not isinstance(n_streams, (int, np.integer)):
        raise ValueError(f"n_streams must be an integer, got {n_streams!r}")  # noqa: TRY004
    n = int(n_streams)
    if not 1 <= n <= MAX_STREAMS:
        raise ValueError(
            f"n_streams (per hemisphere) must be in [1, {MAX_STREAMS}], got {n}"
        )
    floor_albedo = _real("floor_albedo", floor_albedo)
    if not 0.0 <= floor_albedo <= 1.0:
        raise ValueError(f"floor_albedo must be in [0, 1], got {floor_albedo}")
    if math.isinf(tau) and floor_albedo != 0.0:
        raise ValueError(
            "floor_albedo has no effect under a semi-infinite slab (tau = inf); leave it 0"
        )
    if depths is None:
        d = np.zeros(0)
    else:
        try:
            d = np.asarray(depths, dtype=float)
        except (TypeError, ValueError):
            raise ValueError("depths must be an array of optical depths") from None
        if d.ndim > 1:
            raise ValueError("depths must be a scalar or a 1-D array of optical depths")
        d = np.atleast_1d(d)
        if not np.all(np.isfinite(d)) or np.any(d < 0.0) or np.any(d > tau):
            raise ValueError(
                f"depths must be finite optical depths within [0, tau={tau}]"
            )
    chi = np.asarray(phase.legendre_moments(2 * n), dtype=float)
    if chi.shape != (2 * n,) or not np.all(np.isfinite(chi)):
        raise ValueError("phase.legendre_moments returned an invalid array")
    if abs(chi[0] - 1.0) > 1e-6:
        raise ValueError(
            f"phase function is not normalised: chi_0 = {chi[0]:.8g}, expected 1"
        )
    chi = chi.copy()
    chi[0] = 1.0
    return tau, omega, n, d, floor_albedo, chi


def solve_slab(
    *,
    tau: float,
    omega: float,
    mu0: float,
    phase: PhaseFunction,
    n_streams: int = 16,
    depths=None,
    floor_albedo: float = 0.0,
) -> SlabSolution:
    """Solve a homogeneous slab lit by a collimated beam (discrete ordinates).

    Parameters
    ----------
    tau : float
        Optical thickness (dimensionless), 0 <= tau <= inf (``math.inf``: a
        semi-infinite medium). For a spherical-leaf canopy, tau = 0.5 * LAI.
    omega : float
        Single-scattering albedo, 0 <= omega <= 1 (1: conservative, handled
        exactly).
    mu0 : float
        Cosine of the beam's zenith angle, 0 < mu0 <= 1. The beam has
        irradiance 1 on a plane perpendicular to it, so mu0 on the slab top.
    phase : PhaseFunction
        Rotationally symmetric phase function (1/4π normalisation), e.g.
        :func:`~foliage_tools.lighting.phase.hg_phase` or
        :func:`~foliage_tools.lighting.phase.canopy_bilambertian_phase`. Its
        Legendre expansion is truncated after 2 * n_streams terms (no delta-M
        scaling), so very forward-peaked functions need more streams.
    n_streams : int
        Quadrature directions per hemisphere N (2N streams in all), 1..256.
        Default 16: fluxes change by ~1e-8 (HG g = 0.5) to ~3e-7 (g = 0.8)
        from 16 to 32 streams. Without delta-M scaling, Henyey-Greenstein
        needs roughly n_streams >= 0.6/(1 - |g|) near omega = 1 (g = 0.95: 16,
        0.98: 32, 0.99: 64); otherwise a ValueError says so.
    depths : array_like, optional
        Optical depths (0 <= t <= tau, finite) where the flux profiles are
        reported. Default: none.
    floor_albedo : float
        Albedo of a Lambertian floor under the slab, 0..1 (0: black). Must be 0
        when tau = inf.

    Returns
    -------
    SlabSolution
        Fluxes, profiles, nodal radiances and a ``radiance`` method for any
        direction; see :class:`SlabSolution` for the normalisation.

    Raises
    ------
    ValueError
        If an input is out of range, or the phase function is too peaked for
        ``n_streams``.
    """
    tau, omega, n, d, floor_albedo, chi = _validate(
        tau, omega, phase, n_streams, depths, floor_albedo
    )
    mu0 = _real("mu0 (cosine of the beam zenith angle)", mu0)
    if not 0.0 < mu0 <= 1.0:
        raise ValueError(
            f"mu0 (cosine of the beam zenith angle) must be in (0, 1], got {mu0}"
        )
    return _solve(tau, omega, mu0, n, d, floor_albedo, chi)


def solve_slab_diffuse(
    *,
    tau: float,
    omega: float,
    phase: PhaseFunction,
    n_streams: int = 16,
    depths=None,
    floor_albedo: float = 0.0,
) -> SlabSolution:
    """Solve a homogeneous slab lit by a uniform isotropic sky.

    The sky radiance is 1/π (horizontal irradiance 1 on the top). Parameters
    and result as :func:`solve_slab` (``mu0`` is None in the result; all
    transmitted light, including the uncollided sky light, is counted as
    diffuse; the field is azimuthally symmetric). ``reflectance`` is the
    white-sky (bi-hemispherical) albedo. A beam + sky illumination is the sum
    of the two solutions' fluxes scaled by their incident irradiances.
    """
    tau, omega, n, d, floor_albedo, chi = _validate(
        tau, omega, phase, n_streams, depths, floor_albedo
    )
    return _solve(tau, omega, None, n, d, floor_albedo, chi)


def _solve(tau, omega, mu0, n, depths, floor_albedo, chi) -> SlabSolution:
    x, wgl = np.polynomial.legendre.leggauss(n)
    # double-Gauss: Gauss-Legendre on each hemisphere mu in (0, 1) (Sykes 1951)
    mu = 0.5 * (x + 1.0)
    w = 0.5 * wgl
    setup = _Setup(
        n=n,
        mu=mu,
        w=w,
        chi=chi,
        omega=omega,
        tau=tau,
        floor_albedo=floor_albedo,
        mu0=mu0,
    )
    beam = mu0 is not None
    f_inc = mu0 if beam else 1.0
    inf = math.isinf(tau)

    def direct_actinic(t):
        return _decay(1.0 / mu0, t) if beam else np.zeros(np.shape(t))

    if tau == 0.0:
        # exact: nothing in the slab; the floor reflects the incident light.
        up = floor_albedo / math.pi * f_inc
        sky = 0.0 if beam else 1.0 / math.pi
        zeros = np.zeros(depths.shape)
        fd = f_inc if not beam else 0.0
        return _make_solution(
            tau=tau,
            omega=omega,
            mu0=mu0,
            n_streams=n,
            floor_albedo=floor_albedo,
            incident_flux=f_inc,
            reflectance=floor_albedo,
            transmittance_direct=1.0 if beam else 0.0,
            transmittance_diffuse=0.0 if beam else 1.0,
            absorptance=0.0,
            floor_absorptance=1.0 - floor_albedo,
            depths=depths,
            flux_direct=zeros + (mu0 if beam else 0.0),
            flux_down_diffuse=zeros + fd,
            flux_up=zeros + floor_albedo * f_inc,
            actinic_flux=zeros + (1.0 if beam else 0.0) + 2.0 * math.pi * (up + sky),
            actinic_flux_diffuse=zeros + 2.0 * math.pi * (up + sky),
            mu=mu,
            weights=w,
            radiance_up_top=np.full(n, up),
            radiance_down_bottom=np.full(n, sky),
            _field=_Field(setup, None),
        )

    mode0 = _solve_mode(setup, _eigen(setup, 0))
    field_ = _Field(setup, mode0)

    def profile(t):
        t = np.asarray(t, dtype=float)
        if t.size == 0:
            e = np.zeros(0)
            return e, e, e, e, e
        nod = mode0.nodal(t)
        ip, im = nod[:, :n], nod[:, n:]
        da = direct_actinic(t)
        f_dir = mu0 * da if beam else np.zeros(t.shape)
        # at the top the downward radiances are the boundary condition itself (no diffuse light for a beam, 1/pi for
        # the unit sky), which the modes' sum meets only to round-off (-1e-12 at omega 0.94, mu0 0.99, tau 0.5)
        im = np.where((t == 0.0)[:, None], 0.0 if beam else 1.0 / math.pi, im)
        f_dn = 2.0 * math.pi * im @ (w * mu)
        if not inf:  # and at the floor the upward ones are its Lambertian reflection of all that reaches it
            at_floor = floor_albedo / math.pi * (f_dn + f_dir)
            ip = np.where((t == tau)[:, None], at_floor[:, None], ip)
        f_up = 2.0 * math.pi * ip @ (w * mu)
        act_diff = 2.0 * math.pi * (ip + im) @ w
        return f_dir, f_dn, f_up, act_diff + da, act_diff

    f_dir, f_dn, f_up, act, act_diff = profile(depths)
    top = mode0.nodal([0.0])[0]
    bottom = mode0.nodal([tau])[0]
    reflectance = 2.0 * math.pi * float(top[:n] @ (w * mu)) / f_inc
    if inf:
        t_dir = 0.0
        t_diff = 0.0
    else:
        t_dir = float(_decay(1.0 / mu0, tau)) if beam else 0.0
        t_diff = 2.0 * math.pi * float(bottom[n:] @ (w * mu)) / f_inc
    if omega < 1.0:
        integ = mode0.integral()
        act_int = 2.0 * math.pi * float((integ[:n] + integ[n:]) @ w)
        if beam:
            act_int += mu0 if inf else mu0 * float(-np.expm1(-tau / mu0))
        absorptance = (1.0 - omega) * act_int / f_inc
    else:
        absorptance = 0.0
    floor_abs = 0.0 if inf else (1.0 - floor_albedo) * (t_dir + t_diff)
    return _make_solution(
        tau=tau,
        omega=omega,
        mu0=mu0,
        n_streams=n,
        floor_albedo=floor_albedo,
        incident_flux=f_inc,
        reflectance=reflectance,
        transmittance_direct=t_dir,
        transmittance_diffuse=t_diff,
        absorptance=absorptance,
        floor_absorptance=floor_abs,
        depths=depths,
        flux_direct=f_dir,
        flux_down_diffuse=f_dn,
        flux_up=f_up,
        actinic_flux=act,
        actinic_flux_diffuse=act_diff,
        mu=mu,
        weights=w,
        radiance_up_top=top[:n].copy(),
        radiance_down_bottom=bottom[n:].copy(),
        _field=field_,
    )


def _make_solution(**fields) -> SlabSolution:
    """Build a SlabSolution with float scalars and read-only array fields."""
    for name, value in fields.items():
        if isinstance(value, np.ndarray):
            arr = np.array(value, dtype=float)
            arr.setflags(write=False)
            fields[name] = arr
        elif isinstance(value, (float, np.floating)):
            fields[name] = float(value)
    return SlabSolution(**fields)
