"""A copy of the input that travels with a bake: ``foliage bake --portable`` (issue #17).

A bake's first layer sublayers the input by a relative path
(``@../assets/tree.usda@``); moved without the input, the folder opens as an
empty scene with only a console warning. With ``--portable`` the bake first
writes the input's composed stage, flattened into one layer
(``Usd.Stage.Flatten``: sublayers, references and payloads composed; native
instances stay instances, of prototypes flattened into the same layer), as
``OUTDIR/<stem>.input.usda``, with every file its asset paths name (textures,
an upstream bake's ``.vdb``) copied beside it as ``<stem>.input.<name>``
and the paths rewritten to ``./<stem>.input.<name>``. Everything the bake
refers to is then inside OUTDIR, by paths relative to it.

Only files under the input's own folder (or the folder ``--portable-root``
names) are copied: an asset path is the input's to write, so an absolute or
``../`` path, or a symlink under the folder that leads out of it, could
otherwise make a bake copy any file it can read (``@/etc/passwd@``) into its
output. Such a path is kept as it is, with a warning naming it. A sublayer, reference
or payload outside that folder is composed into the copy like any other (the
flattened layer holds no path to it), with a warning naming it.

Flat names, not a subfolder: OUTDIR's files are committed together as one
result (``scene.atomic``), and the commit moves files of one directory.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

from foliage_tools.scene.schemas import register

register()

from pxr import Sdf, Usd, UsdUtils  # noqa: E402


def input_copy_name(path: Path) -> str:
    """``<stem>.input.usda``: the name of the flattened input in OUTDIR."""
    return f"{Path(path).stem}.input.usda"


def write_portable_input(path: Path, directory: Path, warnings: list[str], root: Path | None = None) -> list[Path]:
    """Flatten the stage at ``path`` into ``directory`` (a staging directory) with copies of its asset files.

    Returns the files written, the layer last. Only regular files under
    ``root`` (default: the input's folder), symlinks resolved, are copied.
    Asset paths that name no file (a search path, a ``<UDIM>`` pattern, a
    missing texture) or a file outside ``root`` are kept as they are, with a
    warning that the folder still depends on them.
    """
    path = Path(path)
    directory = Path(directory)
    root = Path(root if root is not None else path.absolute().parent).resolve()
    stage = Usd.Stage.Open(str(path))
    own = Path(stage.GetRootLayer().realPath).resolve()
    composed = sorted({Path(used.realPath).resolve() for used in stage.GetUsedLayers() if used.realPath}
                      - {own}, key=str)
    layer = stage.Flatten()
    layer.documentation = stage.GetRootLayer().documentation  # not Flatten's note naming this machine's path
    # the input's own bake record names files beside the input, not these copies (scene.integrity)
    data = dict(layer.customLayerData)
    if data.pop("foliage", None) is not None:
        layer.customLayerData = data
    prefix = Path(path).stem + ".input."
    copies: dict[Path, str] = {}
    written: list[Path] = []
    missing: set[str] = set()
    foreign: set[str] = set()

    def localize(asset: str) -> str:
        if not asset:
            return asset
        source = Path(asset)
        if not source.is_absolute() or not source.is_file():  # Flatten made every file path absolute
            missing.add(asset)
            return asset
        source = source.resolve()
        if not source.is_relative_to(root):
            foreign.add(asset)
            return asset
        if source not in copies:
            name = prefix + re.sub(r"[^A-Za-z0-9_.-]", "_", source.name)
            taken = set(copies.values()) | {input_copy_name(path)}  # never the flattened layer's own name
            stem, ext = os.path.splitext(name)
            k = 1
            while name in taken:
                name = f"{stem}_{k}{ext}"
                k += 1
            shutil.copy2(source, directory / name)
            written.append(directory / name)
            copies[source] = name
        return f"./{copies[source]}"

    UsdUtils.ModifyAssetPaths(layer, localize)
    target = directory / input_copy_name(path)
    if not layer.Export(str(target)):
        raise OSError(f"cannot write {target}")
    written.append(target)
    for asset in sorted(missing):
        warnings.append(f"--portable: @{asset}@ (named by the input) is not a file that could be copied; the output "
                        "folder still depends on it where it is.")
    for asset in sorted(foreign):
        warnings.append(f"--portable: @{asset}@ (named by the input) lies outside @{root}@, so it was not copied; the "
                        "output folder still depends on it where it is. Move it under that folder, or pass "
                        "--portable-root with a folder that holds it.")
    for used in composed:
        if not used.is_relative_to(root):
            warnings.append(f"--portable: @{used}@ (a sublayer, reference or payload of the input) lies outside "
                            f"@{root}@; its content was composed into @{input_copy_name(path)}@, the output folder's "
                            "copy of the input. Move it under that folder, or pass --portable-root with a folder "
                            "that holds it.")
    return written


def escaping_sublayers(layer: Sdf.Layer) -> list[str]:
    """Sublayer paths of ``layer`` that lead out of its folder (``../``, absolute): moving the folder breaks them."""
    if not layer.realPath:
        return []
    here = Path(layer.realPath).resolve().parent
    found = []
    for sub in layer.subLayerPaths:
        if "://" in sub:
            continue  # a URI resolver's path: the same from anywhere
        target = Path(os.path.normpath(here / sub)) if not Path(sub).is_absolute() else Path(sub)
        try:
            target.resolve().relative_to(here)
        except ValueError:
            found.append(sub)
    return found
