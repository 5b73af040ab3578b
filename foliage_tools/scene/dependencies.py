"""The files a stage is made of: its whole layer stack and the assets its layers name.

``UsdUtils.ComputeAllDependencies`` opens the layers (sublayers, references,
payloads) without composing the stage and lists the asset paths they author
(``.vdb`` grids, textures, ...). Used to refuse outputs that are inputs
(``scene.write``) and to key ``foliage batch``'s cache on the bytes of
everything a bake reads.

Before USD opens any layer, :func:`open_layers` checks that it is a regular
file (:func:`file_problem`: never a FIFO, device, directory or symlink loop,
which USD would block on or fail on without saying why) and opens each one
itself, so that a layer USD cannot read is refused naming that layer and the
layer that names it. Every reader (``scene.read.open_stage``, ``validate``,
:func:`dependencies`) goes through it.
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from foliage_tools.errors import InputError
from foliage_tools.scene.schemas import register

register()  # before the first layer is opened (DESIGN.md section 5)

from pxr import Ar, Sdf, Tf, UsdUtils  # noqa: E402

from foliage_tools.scene.usd_diagnostics import captured, not_utf8, open_failure  # noqa: E402


def shown(path: str | os.PathLike) -> str:
    """``path`` as a message prints it: bytes that are not UTF-8 as ``\\xff`` and control characters (a newline,
    an escape) as ``\\n``, ``\\x1b``, so a hostile file name can neither break a line nor steer a terminal."""
    text = os.fsencode(os.fspath(path)).decode("utf-8", errors="backslashreplace")
    return "".join(c if c.isprintable() or c == " " else c.encode("unicode_escape").decode("ascii") for c in text)


def name_problem(path: str | os.PathLike) -> str | None:
    """Why USD cannot take ``path`` as a file name (it refuses control characters and bytes that are not UTF-8 in
    an asset path), or None."""
    raw = os.fsencode(os.fspath(path))
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        return f"its name holds byte 0x{raw[exc.start]:02x} (not UTF-8)"
    bad = next((c for c in text if ord(c) < 0x20 or ord(c) == 0x7F), None)
    if bad is not None:
        return f"its name holds the control character {bad.encode('unicode_escape').decode('ascii')}"
    return None


def file_problem(path: str | os.PathLike) -> str | None:
    """Why ``path`` is not a readable regular file, from ``os.stat`` alone (nothing is opened, so a FIFO or a
    device never blocks), e.g. "is a FIFO (named pipe), not a regular file"; None when it is one."""
    try:
        st = os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "is a symbolic link that loops (it never reaches a file)"
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            return "does not exist" if not os.path.islink(path) else "is a symbolic link to a file that does not exist"
        if exc.errno == errno.EACCES:
            return "cannot be read (permission denied)"
        if exc.errno == errno.ENAMETOOLONG:
            return "has a name too long for the file system"
        return f"cannot be read ({os.strerror(exc.errno) if exc.errno else exc})"
    mode = st.st_mode
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "is a directory, not a file"
    if stat.S_ISFIFO(mode):
        return "is a FIFO (named pipe), not a regular file"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "is a device, not a regular file"
    if stat.S_ISSOCK(mode):
        return "is a socket, not a regular file"
    return "is not a regular file"


def require_file(path: str | os.PathLike, what: str = "Check the path.") -> None:
    """:class:`InputError` ``@path@ <why>. <what>`` when ``path`` is not a readable regular file."""
    problem = file_problem(path)
    if problem is not None:
        raise InputError(f"@{shown(path)}@ {problem}. {what}")


def _resolved(layer: Sdf.Layer, asset: str) -> str | None:
    """The file ``asset`` (as authored in ``layer``) resolves to, or None when it resolves to none."""
    try:
        anchored = Sdf.ComputeAssetPathRelativeToLayer(layer, asset)
        resolved = str(Ar.GetResolver().Resolve(anchored)) if anchored else ""
    except Tf.ErrorException:
        return None
    return resolved or None


def open_layers(path: str | os.PathLike) -> list[Sdf.Layer]:
    """Open the layer at ``path`` and every layer it reaches (sublayers, references, payloads, in variants too),
    each checked to be a regular file with a name USD takes before it is opened; :class:`InputError` naming the
    first that is not, or that USD cannot read, and the layer naming it.

    Missing layers are left out: USD reports them when it composes (``bakeable.composition_problems``). Hold the
    returned layers while the stage is opened: USD then reads each from its registry instead of the file again.
    """
    root = os.fspath(path)  # as given: USD names the root layer by the identifier it was first opened with
    layers: list[Sdf.Layer] = []
    seen: set[str] = set()
    pending: list[tuple[str, Sdf.Layer | None, str]] = [(root, None, "")]
    while pending:
        file, by, asset = pending.pop()
        real = os.path.realpath(file)
        if real in seen:
            continue
        seen.add(real)
        if by is None:
            named = f"@{shown(file)}@"
        else:  # the input as it was given, a layer below it by its path
            by_name = root if by == layers[0] else (by.realPath or by.identifier)
            named = f"@{shown(by_name)}@ names @{shown(asset)}@, which"
        problem = name_problem(file) or file_problem(file)
        if problem is not None:
            what = ("USD cannot open it: rename it." if name_problem(file) else
                    "Give a USD file (.usd, .usda, .usdc, .usdz)." if by is None else
                    "Point the asset path at a USD file, or remove it.")
            raise InputError(f"{named} {problem}. {what}")
        if by is not None and os.stat(file).st_size == 0:
            raise InputError(f"{named} is empty (0 bytes). Export that layer again, or remove the path.")
        if by is None:
            try:  # a root USD cannot read is its caller's to report (read.open_stage: where a syntax error is)
                with captured():
                    layer = Sdf.Layer.FindOrOpen(file)
            except Tf.ErrorException:
                return layers
            if layer is None:
                return layers
        else:
            layer = _open(file, named)
        layers.append(layer)
        for dep in layer.GetCompositionAssetDependencies():
            target = _resolved(layer, dep)
            if target is not None:
                pending.append((target, layer, dep))
    return layers


def _open(file: str, named: str) -> Sdf.Layer:
    """A dependency layer, opened by Sdf; :class:`InputError` naming it when USD cannot read it."""
    try:
        with captured():
            layer = Sdf.Layer.FindOrOpen(file)
    except Tf.ErrorException as exc:
        undecodable = not_utf8(file)
        if undecodable is not None:
            raise InputError(f"{named} is not UTF-8 text ({undecodable}): USD text layers are UTF-8. Save that layer "
                             "as UTF-8, or remove the path that names it.") from None
        raise InputError(f"{named} cannot be opened as USD ({open_failure(exc, file)}). Fix or re-export that layer, "
                         "or remove the path that names it.") from None
    if layer is None:
        raise InputError(f"{named} cannot be opened as USD. Fix or re-export that layer, or remove the path that "
                         "names it.")
    return layer


def dependencies(path: Path) -> tuple[frozenset[Path], tuple[str, ...]]:
    """Every file the stage at ``path`` reads (resolved, absolute; ``path`` itself included), and the asset
    paths its layers name that resolve to no file, as authored.

    Not cached: a caller that hashes the files must see a sublayer added since.
    An unreadable input, or one reaching a layer that is not a regular file or that USD cannot read, gives just
    itself (the reader reports it, with its own message); so does anything but a regular file among the assets.
    """
    path = Path(path).resolve()
    try:
        root = Path(path)
        if name_problem(root) or file_problem(root):
            return frozenset({path}), ()
        held = open_layers(root)  # noqa: F841  (held open while USD walks them: it reads none of them twice)
        # a missing sublayer or reference is the reader's to report, in its words: USD's own warnings go to the log
        with captured():
            layers, assets, unresolved = UsdUtils.ComputeAllDependencies(Sdf.AssetPath(str(path)))
    except Exception:
        return frozenset({path}), ()
    files = {Path(layer.realPath).resolve() for layer in layers if layer.realPath}
    files.update(Path(a).resolve() for a in assets if a and file_problem(a) is None)
    files.add(path)
    return frozenset(files), tuple(str(u) for u in unresolved)
