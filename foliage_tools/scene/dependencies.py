"""The files a stage is made of: its whole layer stack and the assets its layers name.

``UsdUtils.ComputeAllDependencies`` opens the layers (sublayers, references,
payloads) without composing the stage and lists the asset paths they author
(``.vdb`` grids, textures, ...). Used to refuse outputs that are inputs
(``scene.write``) and to key ``foliage batch``'s cache on the bytes of
everything a bake reads.
"""

from __future__ import annotations

from pathlib import Path

from foliage_tools.scene.schemas import register

register()  # before the first layer is opened (DESIGN.md section 5)

from pxr import Sdf, UsdUtils  # noqa: E402

from foliage_tools.scene.usd_diagnostics import captured  # noqa: E402


def dependencies(path: Path) -> tuple[frozenset[Path], tuple[str, ...]]:
    """Every file the stage at ``path`` reads (resolved, absolute; ``path`` itself included), and the asset
    paths its layers name that resolve to no file, as authored.

    Not cached: a caller that hashes the files must see a sublayer added since.
    An unreadable input gives just itself (the reader reports it, with its own message).
    """
    path = Path(path).resolve()
    try:
        # a missing sublayer or reference is the reader's to report, in its words: USD's own warnings go to the log
        with captured():
            layers, assets, unresolved = UsdUtils.ComputeAllDependencies(Sdf.AssetPath(str(path)))
    except Exception:
        return frozenset({path}), ()
    files = {Path(layer.realPath).resolve() for layer in layers if layer.realPath}
    files.update(Path(a).resolve() for a in assets if a)
    files.add(path)
    return frozenset(files), tuple(str(u) for u in unresolved)
