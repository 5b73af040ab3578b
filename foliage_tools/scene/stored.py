"""What an earlier stage stored in a layer, read back for reuse and checks: a volume's field files, prim attributes.

The pipeline reuses an earlier stage's density grid (DESIGN.md section 3) and
checks the sun a bake recorded; the USD side of both lives here, so only
``scene/`` touches ``pxr`` (issue #20's layering).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["StoredField", "authored_vectors", "volume_fields"]


@dataclass(frozen=True)
class StoredField:
    """One field of a stored UsdVol.Volume: its OpenVDBAsset prim and the file it names."""

    prim: str
    """The field prim's path."""
    asset: str | None
    """The authored file path (None or "" when it names none)."""
    resolved: Path | None
    """The resolved file, None when it does not resolve to an existing file."""
    field_name: str
    """The grid's name in the file (the field's fieldName, else the field's name on the volume)."""


def _stage(path: Path):
    p = Path(path).resolve()
    return _open(str(p), p.stat().st_mtime_ns)


@lru_cache(maxsize=2)
def _open(path: str, _mtime: int):
    """The composed stage, opened once per file version (a bake reads several prototypes' volumes from it)."""
    from pxr import Usd

    return Usd.Stage.Open(path)


def volume_fields(path: str | Path, volume: str, names: tuple[str, ...]) -> dict[str, StoredField] | None:
    """The fields ``names`` of the volume prim ``volume`` on the composed stage of ``path``; None when there is no
    such volume or it lacks one of them."""
    from pxr import UsdVol

    stage = _stage(Path(path))
    vol = UsdVol.Volume(stage.GetPrimAtPath(volume))
    if not vol:
        return None
    fields = vol.GetFieldPaths()
    if any(n not in fields for n in names):
        return None
    out = {}
    for name in names:
        asset = UsdVol.OpenVDBAsset(stage.GetPrimAtPath(fields[name]))
        ap = asset.GetFilePathAttr().Get() if asset else None
        resolved = Path(ap.resolvedPath) if ap is not None and ap.resolvedPath else None
        out[name] = StoredField(prim=str(fields[name]), asset=ap.path if ap is not None else None,
                                resolved=resolved if resolved is not None and resolved.is_file() else None,
                                field_name=(asset.GetFieldNameAttr().Get() if asset else None) or name)
    return out


def authored_vectors(path: str | Path, requests: list[tuple[str, str]]) -> dict[tuple[str, str], np.ndarray]:
    """The authored values of (prim path, attribute name) ``requests`` as float64 arrays; an absent prim or an
    attribute without an authored value is left out. Opened fresh: the layer may have been written since."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(path))
    out = {}
    for prim_path, name in requests:
        prim = stage.GetPrimAtPath(prim_path)
        attr = prim.GetAttribute(name) if prim else None
        if attr and attr.HasAuthoredValue():
            out[(prim_path, name)] = np.asarray(attr.Get(), dtype=np.float64)
    return out
