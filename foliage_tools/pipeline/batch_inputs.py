"""What ``foliage batch`` bakes: its INPUTS (files, directories, manifests) as a list of named assets.

* a USD file (``.usd``, ``.usda``, ``.usdc``, ``.usdz``) is one asset, named by its stem;
* a directory is searched (recursively, hidden directories skipped) for USD
  files; a file that another one found uses (a sublayer, a reference) is part
  of that asset, not an asset of its own;
* a ``.toml`` file is a manifest: ``[[asset]]`` tables, each with ``path``
  (relative to the manifest), an optional ``name`` and any ``foliage bake``
  option under its long name (``resolution = 32``, ``sun = "120,35"``);
  top-level keys apply to every asset of the manifest.

Each asset bakes into ``OUTROOT/<name>/``, so names must be unique: two
``tree.usda`` from different directories are refused, naming both, with the
fix (a manifest giving them names). The option values stay raw here: the
command line checks and converts them as ``foliage bake`` would.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from foliage_tools.errors import InputError, UsageError

USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


@dataclass(frozen=True)
class AssetSpec:
    """One asset of a batch, as its inputs named it."""

    name: str
    """Its directory under OUTROOT (and its key in batch.json)."""
    path: Path
    """The USD file to bake."""
    options: dict = field(default_factory=dict)
    """Raw ``foliage bake`` option values from a manifest (long names, as written); empty for a file or directory."""
    where: str = ""
    """Where it was named, for messages: the argument, or ``@manifest.toml@ [[asset]] 2``."""
    manifest: Path | None = None
    """The manifest that listed it, if one did."""


def collect(inputs: list[Path], outroot: Path) -> list[AssetSpec]:
    """The assets INPUTS name, in order; refuses missing inputs, unknown file types and clashing names."""
    if not inputs:
        raise UsageError("no INPUTS: give USD files, directories holding them, or a manifest (.toml).")
    specs: list[AssetSpec] = []
    for arg in map(Path, inputs):
        if not arg.exists():
            raise InputError(f"@{arg}@: no such file or directory.")
        if arg.is_dir():
            specs += _search(arg, outroot)
        elif arg.suffix.lower() == ".toml":
            specs += _manifest(arg)
        elif arg.suffix.lower() in USD_SUFFIXES:
            specs.append(AssetSpec(name=arg.stem, path=arg, where=f"@{arg}@"))
        else:
            raise InputError(f"@{arg}@ is neither a USD file ({', '.join(USD_SUFFIXES)}) nor a manifest (.toml); "
                             "give USD files, directories holding them, or a manifest.")
    return _unique(specs)


def _search(directory: Path, outroot: Path) -> list[AssetSpec]:
    """The USD files under ``directory`` that no other one found uses (outputs under OUTROOT excluded)."""
    from foliage_tools.scene.dependencies import dependencies

    root = outroot.resolve()
    found = []
    for p in sorted(directory.rglob("*")):
        rel = p.relative_to(directory).parts
        if p.suffix.lower() not in USD_SUFFIXES or any(part.startswith(".") for part in rel) or not p.is_file():
            continue
        if p.resolve().is_relative_to(root):
            continue  # an earlier batch's outputs
        found.append(p)
    used: set[Path] = set()
    for p in found:
        used |= dependencies(p)[0] - {p.resolve()}
    assets = [AssetSpec(name=p.stem, path=p, where=f"@{p}@ (found in @{directory}@)") for p in found if p.resolve() not in used]
    if not assets:
        raise InputError(f"@{directory}@ holds no USD file ({', '.join(USD_SUFFIXES)}) to bake.")
    return assets


def _manifest(path: Path) -> list[AssetSpec]:
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"@{path}@ is not a valid TOML manifest ({exc}).") from None
    tables = data.get("asset")
    if not isinstance(tables, list) or not tables or not all(isinstance(t, dict) for t in tables):
        raise InputError(f"@{path}@: a manifest lists its assets as [[asset]] tables, each with path = \"FILE.usda\"; "
                         "none found.")
    shared = {k: v for k, v in data.items() if k != "asset"}
    bad = [k for k, v in shared.items() if isinstance(v, dict)]
    if bad:
        raise InputError(f"@{path}@: unknown table [{bad[0]}]; a manifest holds [[asset]] tables and top-level option keys.")
    specs = []
    for i, table in enumerate(tables, start=1):
        where = f"@{path}@ [[asset]] {i}"
        if not isinstance(table.get("path"), str):
            raise InputError(f"{where}: no path = \"FILE.usda\" (relative to the manifest).")
        asset = path.parent / table["path"]
        if not asset.is_file():
            raise InputError(f"{where}: @{asset}@: no such file.")
        name = table.get("name", asset.stem)
        if not isinstance(name, str) or not name or name.startswith(".") or "/" in name or name == "batch.json":
            raise InputError(f"{where}: name {name!r} cannot be a directory under OUTROOT; give a plain name.")
        options = {**shared, **{k: v for k, v in table.items() if k not in ("path", "name")}}
        specs.append(AssetSpec(name=name, path=asset, options=options, where=where, manifest=path))
    return specs


def _unique(specs: list[AssetSpec]) -> list[AssetSpec]:
    """Drop exact repeats (one file named twice); refuse two different assets under one name."""
    out: dict[str, AssetSpec] = {}
    for s in specs:
        other = out.get(s.name)
        if other is None:
            out[s.name] = s
        elif other.path.resolve() != s.path.resolve() or other.options != s.options:
            raise UsageError(
                f"two assets would bake into OUTROOT/{s.name}/: {other.where} and {s.where}; list them in a manifest "
                "with distinct names ([[asset]] path = \"...\", name = \"...\").")
    return list(out.values())
