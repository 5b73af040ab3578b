"""The result of a slab problem: :class:`SlabSolution`.

Fluxes, depth profiles and nodal radiances of one solve, normalised as in the
package docstring (:mod:`foliage_tools.lighting.plane_parallel`), with a ``radiance``
method for any depth and direction, backed by :class:`_Field`, which solves the
Fourier orders m > 0 only when a radiance at an azimuth is asked for.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from foliage_tools.lighting.plane_parallel.eigen import _eigen, _Setup
from foliage_tools.lighting.plane_parallel.modes import _solve_mode


# --------------------------------------------------------------------------
# public result type
# --------------------------------------------------------------------------


class _Field:
    """Lazily computed Fourier orders of one slab problem (for user radiances)."""

    def __init__(self, setup: _Setup, mode0):
        self.setup = setup
        self.modes = {0: mode0}

    def mode(self, m: int):
        if m not in self.modes:
            self.modes[m] = _solve_mode(self.setup, _eigen(self.setup, m))
        return self.modes[m]

    def radiance(self, depth, mu, phi):
        setup = self.setup
        if setup.tau == 0.0:
            return self._radiance_tau0(depth, mu, phi)
        out = self.mode(0).user(depth, mu)
        if phi is None or setup.mu0 is None or setup.omega == 0.0 or setup.mu0 == 1.0:
            # azimuthal average, or azimuthally symmetric field
            return out
        for m in range(1, 2 * setup.n):
            out = out + self.mode(m).user(depth, mu) * np.cos(m * phi)
        return out

    def _radiance_tau0(self, depth, mu, phi):
        setup = self.setup
        if setup.mu0 is None:
            incident = 1.0
            sky = 1.0 / math.pi
        else:
            incident = setup.mu0
            sky = 0.0
        up = setup.floor_albedo / math.pi * incident
        return np.where(np.asarray(mu) > 0.0, up, sky) + 0.0 * np.asarray(
            depth, dtype=float
        )


@dataclass(frozen=True, eq=False)
class SlabSolution:
    """Solution of the slab problem. See the package docstring for normalisation.

    Attributes
    ----------
    tau, omega, mu0, n_streams, floor_albedo :
        The problem solved (``mu0`` is None for isotropic sky illumination).
    incident_flux : float
        Horizontal irradiance entering the top: ``mu0`` (beam) or 1 (sky).
    reflectance : float
        Plane albedo: upward diffuse flux leaving the top / ``incident_flux``.
    transmittance_direct : float
        Unscattered beam reaching the bottom / ``incident_flux`` = exp(-tau/mu0)
        (0 for sky illumination, whose uncollided part is counted as diffuse;
        0 for tau = inf).
    transmittance_diffuse : float
        Downward diffuse flux at the slab bottom (above the floor) /
        ``incident_flux`` (0 for tau = inf).
    absorptance : float
        Power absorbed in the slab / ``incident_flux``, computed independently
        of the boundary fluxes as (1 - omega) ∫_0^tau (actinic flux) dt.
    floor_absorptance : float
        Power absorbed by the floor / ``incident_flux``
        = (1 - floor_albedo) (downward flux at the bottom). With the above,
        reflectance + absorptance + floor_absorptance = 1.
    depths : ndarray (D,)
        The requested optical depths t (downward from the top).
    flux_direct : ndarray (D,)
        Horizontal irradiance of the unscattered beam, mu0 exp(-t/mu0)
        (per unit beam irradiance; zeros for sky illumination).
    flux_down_diffuse, flux_up : ndarray (D,)
        Downward and upward diffuse horizontal irradiance 2π ∫ |mu| I dmu.
    actinic_flux : ndarray (D,)
        Scalar irradiance 4π J = ∫ I dΩ including the direct beam
        (exp(-t/mu0) for the beam). The mean irradiance on one face of a
        randomly (uniformly) oriented flat leaf is actinic_flux / 4.
    actinic_flux_diffuse : ndarray (D,)
        Diffuse part of ``actinic_flux``. Mean intensity J = actinic_flux/(4π).
    mu, weights : ndarray (N,)
        Double-Gauss nodes (cosines, 0 < mu < 1) and weights (sum 1) of one
        hemisphere.
    radiance_up_top : ndarray (N,)
        Azimuthally averaged diffuse radiance leaving the top upward at the
        nodes ``mu`` (sr⁻¹ per unit incident irradiance).
    radiance_down_bottom : ndarray (N,)
        Azimuthally averaged diffuse radiance going downward at the bottom
        (t = tau) at cosines ``mu`` from the downward vertical; for tau = inf
        the limit t -> inf (zero unless omega = 1).
    """

    tau: float
    omega: float
    mu0: float | None
    n_streams: int
    floor_albedo: float
    incident_flux: float
    reflectance: float
    transmittance_direct: float
    transmittance_diffuse: float
    absorptance: float
    floor_absorptance: float
    depths: np.ndarray
    flux_direct: np.ndarray
    flux_down_diffuse: np.ndarray
    flux_up: np.ndarray
    actinic_flux: np.ndarray
    actinic_flux_diffuse: np.ndarray
    mu: np.ndarray
    weights: np.ndarray
    radiance_up_top: np.ndarray
    radiance_down_bottom: np.ndarray
    _field: _Field = field(repr=False, compare=False)

    @property
    def transmittance(self) -> float:
        """Total (direct + diffuse) transmittance."""
        return self.transmittance_direct + self.transmittance_diffuse

    def radiance(self, depth, mu, phi=None) -> np.ndarray:
        """Diffuse radiance at optical depth(s) ``depth`` in direction(s) (mu, phi).

        Parameters
        ----------
        depth : array_like
            Optical depth(s) t, 0 <= t <= tau (finite).
        mu : array_like
            Cosine of the direction from the *upward* vertical, -1 <= mu <= 1,
            mu != 0 (> 0: upward-going radiance, < 0: downward-going).
        phi : array_like or None
            Azimuth (radians) of the direction relative to the incident beam's
            propagation azimuth. None: azimuthal average (Fourier order 0 only).

        Returns
        -------
        numpy.ndarray
            Radiance (sr⁻¹ per unit incident irradiance as in the package
            docstring), broadcast shape of the inputs. The direct beam (a delta
            function) is not included.
        """
        if phi is None:
            depth_b, mu_b = np.broadcast_arrays(
                np.asarray(depth, dtype=float), np.asarray(mu, dtype=float)
            )
            phi_b = None
        else:
            depth_b, mu_b, phi_b = np.broadcast_arrays(
                np.asarray(depth, dtype=float),
                np.asarray(mu, dtype=float),
                np.asarray(phi, dtype=float),
            )
        if (
            not np.all(np.isfinite(depth_b))
            or np.any(depth_b < 0.0)
            or np.any(depth_b > self.tau)
        ):
            raise ValueError(f"depth must be finite and within [0, tau={self.tau}]")
        if (
            not np.all(np.isfinite(mu_b))
            or np.any(np.abs(mu_b) > 1.0)
            or np.any(mu_b == 0.0)
        ):
            raise ValueError(
                "mu must be in [-1, 1] and non-zero (> 0 upward, < 0 downward)"
            )
        if phi_b is not None and not np.all(np.isfinite(phi_b)):
            raise ValueError("phi must be finite")
        shape = mu_b.shape
        out = self._field.radiance(
            depth_b.ravel(), mu_b.ravel(), None if phi_b is None else phi_b.ravel()
        )
        return np.asarray(out, dtype=float).reshape(shape)

    def radiance_top(self, mu, phi=None) -> np.ndarray:
        """Diffuse radiance leaving the top upward; ``mu`` in (0, 1] from the upward vertical."""
        mu = np.asarray(mu, dtype=float)
        if np.any(mu <= 0.0):
            raise ValueError(
                "radiance_top needs mu in (0, 1] (cosine from the upward vertical)"
            )
        return self.radiance(0.0, mu, phi)

    def radiance_bottom(self, mu, phi=None) -> np.ndarray:
        """Diffuse radiance leaving the bottom downward; ``mu`` in (0, 1] from the downward vertical."""
        mu = np.asarray(mu, dtype=float)
        if np.any(mu <= 0.0):
            raise ValueError(
                "radiance_bottom needs mu in (0, 1] (cosine from the downward vertical)"
            )
        if math.isinf(self.tau):
            raise ValueError("a semi-infinite slab (tau = inf) has no bottom")
        return self.radiance(self.tau, -mu, phi)
