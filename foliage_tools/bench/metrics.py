"""Error measures of DESIGN.md section 3, comparing per-leaf irradiance against the reference.

All take arrays of shape (L,) or (L, 3) (RGB): sums run over leaves and channels.
"""

from __future__ import annotations

import numpy as np


def rel_rms(x: np.ndarray, ref: np.ndarray) -> float:
    """Relative RMS error ``sqrt(Σ (x − r)² / Σ r²)`` (DESIGN.md section 3); inf if the reference is all zero and x is not."""
    x = np.asarray(x, dtype=np.float64)
    r = np.asarray(ref, dtype=np.float64)
    if x.shape != r.shape:
        raise ValueError(f"shape mismatch: {x.shape} vs reference {r.shape}")
    num = float(np.sum((x - r) ** 2))
    den = float(np.sum(r**2))
    if den == 0.0:
        return 0.0 if num == 0.0 else float("inf")
    return float(np.sqrt(num / den))


def binned_rms(x: np.ndarray, ref: np.ndarray, depth: np.ndarray, thickness: np.ndarray, *, bins: int = 8) -> float:
    """shinya2013 eq. (30): RMS over depth–thickness classes of the class-averaged irradiance.

    The printed formula, ``sqrt(Σ (⟨L⟩² − ⟨L0⟩²) / Σ ⟨L0⟩²)``, can be negative under
    the root; we read it as the usual ``sqrt(Σ_b (⟨L⟩_b − ⟨L0⟩_b)² / Σ_b ⟨L0⟩_b²)``
    over the non-empty classes b of a ``bins × bins`` grid of (depth, thickness)
    quantiles, each class average taken over its leaves (and channels kept apart).

    Parameters
    ----------
    x, ref : (L,) or (L, 3)
        Method and reference irradiance per leaf.
    depth, thickness : (L,)
        Optical depth and thickness of each leaf toward the sun (shinya2013 eq. (29)).
    """
    x = np.asarray(x, dtype=np.float64)
    r = np.asarray(ref, dtype=np.float64)
    d = np.asarray(depth, dtype=np.float64)
    w = np.asarray(thickness, dtype=np.float64)
    if x.shape != r.shape or d.shape != (x.shape[0],) or w.shape != d.shape:
        raise ValueError(f"shape mismatch: x {x.shape}, ref {r.shape}, depth {d.shape}, thickness {w.shape}")
    if x.shape[0] == 0:
        return 0.0

    def classes(v: np.ndarray) -> np.ndarray:
        edges = np.unique(np.quantile(v, np.linspace(0, 1, bins + 1)[1:-1]))
        return np.searchsorted(edges, v, side="right")

    cls = classes(d) * (bins + 1) + classes(w)
    _, inv, counts = np.unique(cls, return_inverse=True, return_counts=True)
    x2 = x.reshape(x.shape[0], -1)
    r2 = r.reshape(r.shape[0], -1)
    mean_x = np.stack([np.bincount(inv, weights=x2[:, c]) for c in range(x2.shape[1])], axis=1) / counts[:, None]
    mean_r = np.stack([np.bincount(inv, weights=r2[:, c]) for c in range(r2.shape[1])], axis=1) / counts[:, None]
    return rel_rms(mean_x, mean_r)


def noise_floor(half_a: np.ndarray, half_b: np.ndarray) -> float:
    """Relative RMS noise of the full reference from two independent half runs.

    Each half has twice the variance of the full run (half the paths), and the
    difference of two halves has twice that again: Var(a − b) = 4 Var(full).
    Hence noise(full) ≈ ‖a − b‖ / (2 ‖(a + b)/2‖) = ‖a − b‖ / ‖a + b‖.
    """
    a = np.asarray(half_a, dtype=np.float64)
    b = np.asarray(half_b, dtype=np.float64)
    den = float(np.linalg.norm(a + b))
    return 0.0 if den == 0.0 else float(np.linalg.norm(a - b) / den)
