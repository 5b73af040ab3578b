"""The preview's GL plumbing: the headless context, shader sources, and the numpy side of uploads and read-backs.

Matrices go to GLSL column-major (``_mat``), instances as one buffer of
model and normal matrices (``INSTANCE_LAYOUT``, ``_instance_data``), and a
supersampled read-back is box-filtered to pixels (``_box_filter``). The
passes that use them are in :mod:`foliage_tools.preview.renderer`.
"""

from __future__ import annotations

from importlib import resources
from typing import Any

import numpy as np

from foliage_tools.errors import OutputError


def _shader(name: str) -> str:
    return (resources.files("foliage_tools.preview") / "shaders" / name).read_text(encoding="utf-8")


def _mat(m: np.ndarray) -> bytes:
    """numpy (row-major) 4×4 -> GLSL column-major bytes."""
    return np.ascontiguousarray(np.asarray(m, dtype=np.float64).T, dtype=np.float32).tobytes()


INSTANCE_LAYOUT = ("16f 9f/i", "in_model", "in_normal_matrix")


def _instance_data(transforms: np.ndarray) -> np.ndarray:
    """(N, 25) float32 per instance: the column-major 4×4 matrix, then the column-major 3×3 normal matrix.

    The normal matrix, the inverse transpose of the linear part, maps a front
    normal to the front normal of the transformed surface, mirrors included.
    """
    t = np.asarray(transforms, dtype=np.float64).reshape(-1, 4, 4)
    lin = t[:, :3, :3]
    # a zero-scale instance draws nothing (its triangles collapse); give it a zero normal matrix
    ok = np.abs(np.linalg.det(lin)) > 1e-300
    normal = np.zeros_like(lin)
    normal[ok] = np.linalg.inv(lin[ok]).transpose(0, 2, 1)
    out = np.empty((len(t), 25), np.float32)
    out[:, :16] = t.transpose(0, 2, 1).reshape(-1, 16)
    out[:, 16:] = normal.transpose(0, 2, 1).reshape(-1, 9)
    return out


def _padded(rows: np.ndarray, n: int) -> np.ndarray:
    out = np.zeros((n, rows.shape[1] if rows.ndim == 2 and rows.size else 3))
    out[: len(rows)] = rows
    return out


def _box_filter(samples: np.ndarray, k: int) -> np.ndarray:
    """Average each k×k block of a (kH, kW, ...) array: one pixel from its supersamples.

    Summing k² strided views is several times faster than ``reshape().mean()``
    on large float32 images; float32 is ample for a mean of at most 16 values.
    """
    if k == 1:
        return np.ascontiguousarray(samples)
    acc = np.zeros((samples.shape[0] // k, samples.shape[1] // k, *samples.shape[2:]), np.float32)
    for i in range(k):
        for j in range(k):
            acc += samples[i::k, j::k]
    acc *= np.float32(1.0 / (k * k))
    return acc


def create_context():
    """A headless OpenGL >= 3.3 context: EGL first (no display needed), then the platform default."""
    import moderngl

    errors = []
    attempts: tuple[dict[str, Any], ...] = ({"backend": "egl"}, {})
    for kwargs in attempts:
        try:
            return moderngl.create_standalone_context(require=330, **kwargs)
        except Exception as exc:  # moderngl raises plain Exception for every context failure
            errors.append(f"{kwargs.get('backend', 'default')}: {exc}")
    raise OutputError(
        "cannot create an OpenGL 3.3 context for the preview (" + "; ".join(errors) + "). On a headless Linux "
        "machine install Mesa's EGL drivers (apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri)."
    )
