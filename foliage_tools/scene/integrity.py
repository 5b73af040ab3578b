"""Which grid files and upstream layers a layer was written with, and whether they are still those files.

Every layer foliage-tools writes records in its ``customLayerData``::

    dictionary foliage = {
        string commit = "..."          # shared by the files written together
        string written = "2026-...Z"   # UTC
        string version = "..."
        dictionary files = {           # asset path as authored -> content hash
            string "./tree.lb.vdb" = "sha256:..."
            string "./tree.spp.usda" = "sha256:..."
        }
    }

``files`` holds every ``.vdb`` the layer refers to and every sublayer that
carries such a record itself (an upstream stage's layer; the raw input asset
is not recorded, so editing it does not make bakes "stale"). A layer and a
file from different runs — a run killed between two renames, a file copied
over, two writers — differ from the record: :func:`check_layers` finds that
and names the stale file (the older of the two).
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import os
import secrets
from functools import lru_cache
from pathlib import Path
from typing import Callable, Iterable

from foliage_tools import __version__
from foliage_tools.errors import InputError
from foliage_tools.scene.atomic import pending_commits
from foliage_tools.scene.schemas import register

register()

from pxr import Sdf  # noqa: E402

SEAL_KEY = "foliage"
USD_SUFFIXES = (".usda", ".usdc", ".usd")


def new_commit_id() -> str:
    return secrets.token_hex(8)


def utc_now() -> str:
    """The time a file is written, as recorded (ISO 8601, UTC, microseconds: strings sort as times)."""
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def written(path: Path) -> str | None:
    """When foliage-tools wrote ``path``, as recorded in the file itself (a layer's record, a grid's metadata), or None."""
    path = Path(path)
    if path.suffix == ".vdb":
        from foliage_tools.scene.vdb import file_metadata

        value = file_metadata(path).get("foliage:written")
    else:
        value = (record_of(path) or {}).get("written")
    return str(value) if value else None


def _older(a: Path, b: Path) -> Path:
    """The one of two files written earlier: by their recorded times, else (a file from elsewhere) by mtime."""
    ta, tb = written(a), written(b)
    if ta and tb and ta != tb:
        return a if ta < tb else b
    return a if a.stat().st_mtime_ns < b.stat().st_mtime_ns else b


def digest(path: Path) -> str:
    """``sha256:<hex>`` of a file's content (cached per file version)."""
    st = os.stat(path)
    return _digest(str(Path(path).resolve()), st.st_size, st.st_mtime_ns, st.st_ino)


@lru_cache(maxsize=256)
def _digest(path: str, _size: int, _mtime: int, _ino: int) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return "sha256:" + h.hexdigest()


def record_of(path: Path) -> dict | None:
    """The ``foliage`` record of the layer file at ``path`` (read from disk, metadata only), or None."""
    if Path(path).suffix not in USD_SUFFIXES or not Path(path).is_file():
        return None
    try:
        layer = Sdf.Layer.OpenAsAnonymous(str(path), metadataOnly=True)
    except Exception:  # an unreadable layer is reported by whoever reads it
        return None
    if layer is None:
        return None
    data = layer.customLayerData.get(SEAL_KEY)
    return dict(data) if data else None


def _asset_paths(layer: Sdf.Layer) -> list[str]:
    """The asset paths authored as attribute defaults in ``layer`` (e.g. OpenVDBAsset ``filePath``)."""
    found = []

    def visit(path: Sdf.Path) -> None:
        if not path.IsPropertyPath():
            return
        spec = layer.GetAttributeAtPath(path)
        if spec and spec.typeName == Sdf.ValueTypeNames.Asset and isinstance(spec.default, Sdf.AssetPath):
            found.append(spec.default.path)

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return found


def locator(staging: Path, final_dir: Path) -> Callable[[str], Path]:
    """Where an asset path of a staged layer points: a file staged beside it, else relative to its final directory."""

    def locate(asset: str) -> Path:
        norm = os.path.normpath(asset)
        if os.sep not in norm and (Path(staging) / norm).exists():
            return Path(staging) / norm
        return Path(os.path.normpath(Path(final_dir) / asset))

    return locate


def seal(layer: Sdf.Layer, locate: Callable[[str], Path], commit: str) -> None:
    """Record in ``layer`` (not saved) the content hash of its grid files and of its recorded sublayers."""
    files = {}
    for asset in _asset_paths(layer):
        if asset.endswith(".vdb") and locate(asset).is_file():
            files[asset] = digest(locate(asset))
    for sub in layer.subLayerPaths:
        target = locate(sub)
        if record_of(target) is not None:
            files[sub] = digest(target)
    data = dict(layer.customLayerData)
    data[SEAL_KEY] = {
        "commit": commit,
        "written": utc_now(),
        "version": __version__,
        "files": files,
    }
    layer.customLayerData = data


def _pending_hint(directory: Path, names: set[str]) -> str:
    for staging, staged in pending_commits(directory):
        if names & set(staged):
            return (f" An interrupted write left the rest of a newer result in @{staging}@: the next foliage run "
                    "writing the same output finishes it.")
    return ""


def _own_references(layer_path: Path) -> set[str]:
    """The asset paths :func:`seal` may record for the layer at ``layer_path``: its ``.vdb`` assets and its sublayers."""
    layer = Sdf.Layer.OpenAsAnonymous(str(layer_path))
    if layer is None:
        return set()
    return ({a for a in _asset_paths(layer) if a.endswith(".vdb")}
            | {s for s in layer.subLayerPaths if s.endswith(USD_SUFFIXES)})


def _written_by_us(layer_path: Path, asset: object, recorded: object) -> bool:
    """Whether a ``files`` entry of the layer's record is one :func:`seal` writes: a relative path (``./x``, ``../x``)
    the layer itself names as a grid file or a sublayer, with a ``sha256:`` hash. Only such entries are opened."""
    if not isinstance(asset, str) or not isinstance(recorded, str) or not recorded.startswith("sha256:"):
        return False
    if not asset.startswith(("./", "../")):
        return False
    return asset in _own_references(layer_path)


def check_layer(layer_path: Path) -> list[str]:
    """Messages for every recorded file beside the layer at ``layer_path`` that is not the one it was written with.

    Raises :class:`InputError` for a record that lists a file the layer does not name (not a record :func:`seal`
    wrote): none of its files is opened then."""
    layer_path = Path(layer_path)
    record = record_of(layer_path)
    if not record:
        return []
    files = dict(record.get("files") or {})
    forged = sorted(str(a) for a in files if not _written_by_us(layer_path, a, files[a]))
    if forged:
        raise InputError(
            f"@{layer_path}@: its foliage record (customLayerData foliage.files) lists @{forged[0]}@, which is not a "
            "grid file or a sublayer this layer names, so the record is not one foliage wrote; no file it lists was "
            f"read. Run the command that writes @{layer_path.name}@ again, or remove the record from the layer.")
    problems = []
    for asset, recorded in files.items():
        f = Path(os.path.normpath(layer_path.parent / asset))
        if not f.is_file():
            continue  # a missing file is reported where it is read (validate's volume-grids rule, USD composition)
        found = digest(f)
        if found == recorded:
            continue
        stale = _older(layer_path, f)
        problems.append(
            f"@{layer_path}@ was written with another @{asset}@ than the one there now (content {recorded[7:19]}… recorded, "
            f"{found[7:19]}… found): the two come from different runs, and @{stale}@, the older, is stale. Run the "
            f"command that writes @{layer_path.name}@ again." + _pending_hint(layer_path.parent, {layer_path.name, f.name})
        )
    return problems


def check_layers(paths: Iterable[Path]) -> list[str]:
    """:func:`check_layer` for every USD layer among ``paths`` (e.g. all the layers a stage uses)."""
    problems = []
    for p in sorted({Path(p) for p in paths if Path(p).suffix in USD_SUFFIXES}):
        problems.extend(check_layer(p))
    return problems


def pending_for(layer_path: Path) -> Path | None:
    """A staging directory beside ``layer_path`` holding a committed but unfinished newer version of it, if any."""
    layer_path = Path(layer_path)
    for staging, staged in pending_commits(layer_path.parent):
        if layer_path.name in staged:
            return staging
    return None
