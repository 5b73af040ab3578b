"""``foliage batch``'s content-hash cache and its record, ``OUTROOT/batch.json``.

An asset's key is the SHA-256 of
* the bytes of every file its stage reads: the whole layer stack and the
  assets the layers name (``scene.dependencies``: sublayers, references,
  payloads, ``.vdb`` grids, textures), each under its path relative to the
  asset's own file, plus the asset paths that resolve to no file;
* the bake's options (``BakeParams``, the leaf optics as numbers, so a
  changed preset counts);
* the tool: its version and a hash of the ``foliage_tools`` sources, so a
  changed solver rebakes even before the version moves.

Modification times play no part: touching a file changes nothing, editing a
sublayer or a texture changes the key of every asset that reads it, and only
those. An asset is cached when its key equals the one batch.json recorded
for its last successful bake and every output recorded then is still there.

batch.json (written atomically, after every asset, so an interrupted batch
resumes where it stopped) holds per asset: ``status`` (``baked``, ``cached``
or ``failed``), ``key``, ``seconds``, ``outputs`` (relative to OUTROOT),
``warnings``, ``error`` (``code``, ``type``, ``message``), and what the key
was made of (``files``: {path: sha256}, ``options``, ``tool``), so a later
run can say why it rebakes.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from foliage_tools import __version__
from foliage_tools.errors import InputError
from foliage_tools.pipeline.bake import BakeParams

RECORD = "batch.json"


@dataclass(frozen=True)
class Key:
    """An asset's cache key and what it was made of."""

    digest: str
    files: dict[str, str | None]
    """{path relative to the asset's file (absolute when outside its directory): sha256}; missing assets: None."""
    options: dict
    tool: str


def options_json(params: BakeParams) -> dict:
    """The bake options as plain JSON values (the leaf optics as numbers)."""
    d = params.direct
    return {
        "optics": params.optics.as_dict(), "sun": list(params.sun) if params.sun is not None else None,
        "resolution": params.resolution, "with_reference": params.with_reference,
        "reference_paths": params.reference_paths, "reference_noise": params.reference_noise,
        "direct": {"mode": d.mode, "samples": d.samples, "seed": d.seed},
        # they change what is written too (the per-leaf scattered light; the volumes' purpose; the layers' files)
        "gather": params.gather, "volume_purpose": params.volume_purpose, "layer_format": params.layer_format,
        "grid_precision": params.grid_precision,  # the lb grids' precision on disk
    }


@cache
def tool_version() -> str:
    """``VERSION+HASH``: the version and the SHA-256 (12 digits) of every ``foliage_tools`` source file."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for dirpath, dirnames, filenames in os.walk(root):  # symlinked cli/ and schemas/ are not followed: they compute nothing
        dirnames[:] = sorted(d for d in dirnames if d != "__pycache__")
        for name in sorted(filenames):
            if name.endswith(".py") or name.endswith(".glsl"):
                p = Path(dirpath) / name
                h.update(str(p.relative_to(root)).encode() + b"\0" + p.read_bytes() + b"\0")
    return f"{__version__}+{h.hexdigest()[:12]}"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def asset_key(path: Path, params: BakeParams) -> Key:
    """The key of baking ``path`` with ``params`` (module docstring)."""
    from foliage_tools.scene.dependencies import dependencies

    files, unresolved = dependencies(path)
    base = Path(path).resolve().parent
    digests: dict[str, str | None] = {}
    for f in sorted(files):
        name = str(f.relative_to(base)) if f.is_relative_to(base) else str(f)
        try:
            digests[name] = _sha256(f)
        except OSError as exc:
            raise InputError(f"@{f}@ (read by @{path}@): cannot be read ({exc.strerror}).") from None
    for u in unresolved:
        digests.setdefault(u, None)
    options = options_json(params)
    tool = tool_version()
    blob = json.dumps({"files": digests, "options": options, "tool": tool}, sort_keys=True, allow_nan=False)
    return Key(digest=hashlib.sha256(blob.encode()).hexdigest(), files=digests, options=options, tool=tool)


def load_record(outroot: Path) -> dict:
    """The assets of OUTROOT/batch.json ({} when there is none yet); refuses one that is not a batch record."""
    path = Path(outroot) / RECORD
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"@{path}@ is not a batch record ({exc}); move it away (every asset then bakes again).") from None
    if not isinstance(data, dict) or not isinstance(data.get("assets"), dict):
        raise InputError(f"@{path}@ is not a batch record (no \"assets\" object); move it away (every asset then bakes again).")
    return data["assets"]


def write_record(outroot: Path, assets: dict) -> Path:
    """Write OUTROOT/batch.json atomically (a temporary file renamed over it)."""
    from foliage_tools.scene.atomic import atomic_outputs

    path = Path(outroot) / RECORD
    data = {"command": "batch", "version": __version__, "tool": tool_version(),
            "updated": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "assets": dict(sorted(assets.items()))}
    with atomic_outputs([path]) as temps:
        temps[path].write_text(json.dumps(data, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    return path


def why_bake(key: Key, previous: dict | None, outroot: Path, name: str | None = None) -> str | None:
    """Why the asset must bake (a sentence), or None when its last bake is still valid (a cache hit).

    A hit needs every recorded output to be a file of the asset's own folder under OUTROOT (``name``: the asset's
    name, that folder's) that is there now: a record naming files elsewhere is not one a batch wrote."""
    if previous is None:
        return "not baked before (no entry in batch.json)"
    if previous.get("status") not in ("baked", "cached"):
        return "its last run failed"
    if previous.get("tool") != key.tool:
        return f"foliage-tools changed ({previous.get('tool')} -> {key.tool})"
    old_opts = previous.get("options") or {}
    changed = sorted(k for k in set(old_opts) | set(key.options) if old_opts.get(k) != key.options.get(k))
    if changed:
        return "options changed: " + ", ".join(f"{k} {old_opts.get(k)!r} -> {key.options.get(k)!r}" for k in changed)
    old_files = previous.get("files") or {}
    parts = []
    for label, names in (("changed", [f for f in key.files if f in old_files and old_files[f] != key.files[f]]),
                         ("new", [f for f in key.files if f not in old_files]),
                         ("no longer read", [f for f in old_files if f not in key.files])):
        if names:
            parts.append(f"{label}: {', '.join(sorted(names))}")
    if parts:
        return "inputs " + "; ".join(parts)
    if previous.get("key") != key.digest:
        return "its key changed"
    outputs = previous.get("outputs")
    if not isinstance(outputs, list) or not outputs:
        return "its outputs are missing (none recorded)"
    foreign = [str(o) for o in outputs if not _own_output(o, outroot, name)]
    if foreign:
        return (f"batch.json records outputs that are not its own files in its folder under OUTROOT "
                f"({', '.join(foreign)}), so the record is not one foliage wrote")
    missing = [o for o in outputs if not (Path(outroot) / o).is_file()]
    if missing:
        return f"its outputs are missing ({', '.join(missing)})"
    return None


def _own_output(output: object, outroot: Path, name: str | None) -> bool:
    """Whether a recorded output is what a batch records: ``<folder>/<file>`` relative to OUTROOT (the folder the
    asset's name, when given), naming a file that, links resolved, lies in OUTROOT/<folder>/."""
    if not isinstance(output, str) or "\\" in output:
        return False
    parts = output.split("/")
    if len(parts) != 2 or any(p in ("", ".", "..") for p in parts) or (name is not None and parts[0] != name):
        return False
    folder = (Path(outroot) / parts[0]).resolve()
    return (Path(outroot) / output).resolve().parent == folder and folder.parent == Path(outroot).resolve()
