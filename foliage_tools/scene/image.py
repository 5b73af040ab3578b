"""Image files: the only OpenImageIO code. Plain numpy arrays in, files out (and back, for tests).

Formats follow the extension:

* ``.png`` -- 8-bit, for display: pixels are display-encoded values in [0, 1]
  (already tone-mapped and sRGB-encoded), stored with ``oiio:ColorSpace = sRGB``.
* ``.exr`` -- half float, zip-compressed, for compositing and measurement:
  pixels are linear scene radiance, stored as written.

Every write is atomic (DESIGN.md section 3): the file is written to a
temporary sibling with the same extension and renamed into place, so a failed
or interrupted run leaves no partial image.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from collections.abc import Callable, Iterator

import numpy as np
import OpenImageIO as oiio

from foliage_tools.errors import InputError, OutputError, UsageError
from foliage_tools.scene.atomic import atomic_outputs, check_writable

IMAGE_FORMATS = {".png": "png", ".exr": "exr"}
CHANNEL_NAMES = {1: ("Y",), 2: ("Y", "A"), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}


def image_format(path: str | os.PathLike) -> str:
    """``png`` or ``exr`` from the extension; a :class:`UsageError` for anything else."""
    ext = Path(path).suffix.lower()
    if ext not in IMAGE_FORMATS:
        raise UsageError(f"@{path}@: the image format follows the extension; use .png (8-bit, tone-mapped) or .exr (linear radiance), not {ext or 'no extension'!r}.")
    return IMAGE_FORMATS[ext]


def _as_hwc(pixels: np.ndarray) -> np.ndarray:
    a = np.asarray(pixels)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in CHANNEL_NAMES or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"an image must be (H, W) or (H, W, C) with C in 1..4, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError("an image to write holds NaN or infinite values")
    return a


def _write(path: Path, pixels: np.ndarray, fmt: str, final: Path) -> None:
    a = _as_hwc(pixels)
    h, w, c = a.shape
    if fmt == "png":
        data = np.round(np.clip(a, 0.0, 1.0) * 255.0).astype(np.uint8)
        spec = oiio.ImageSpec(w, h, c, oiio.UINT8)
        spec.attribute("oiio:ColorSpace", "sRGB")
    else:
        data = np.ascontiguousarray(a, dtype=np.float32)
        spec = oiio.ImageSpec(w, h, c, oiio.HALF)
        spec.attribute("compression", "zip")
        spec.attribute("oiio:ColorSpace", "lin_rec709")
    spec.channelnames = CHANNEL_NAMES[c]
    if c in (2, 4):
        spec.alpha_channel = c - 1
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise OutputError(f"@{final}@: OpenImageIO cannot write {fmt} files ({oiio.geterror() or 'no plugin'}).")
    try:
        if not out.open(str(path), spec):
            raise OutputError(f"@{final}@: cannot be written ({out.geterror() or 'open failed'}); check the directory.")
        if not out.write_image(np.ascontiguousarray(data)):
            raise OutputError(f"@{final}@: writing the pixels failed ({out.geterror() or 'unknown error'}).")
    finally:
        out.close()


def write_image(path: str | os.PathLike, pixels: np.ndarray) -> Path:
    """Write one image atomically; the format follows the extension (module doc). Returns the path."""
    return write_images([(Path(path), pixels)])[0]


def write_images(images: list[tuple[Path, np.ndarray]]) -> list[Path]:
    """Write several images, all or none (e.g. the frames of a sequence)."""
    paths = [Path(p) for p, _ in images]
    with image_sequence(paths) as write:
        for p, pixels in images:
            write(Path(p), pixels)
    return paths


@contextlib.contextmanager
def image_sequence(paths: list[Path]) -> Iterator[Callable[[Path, np.ndarray], None]]:
    """Yield ``write(path, pixels)`` for images that appear together or not at all.

    Each ``write`` goes to a temporary sibling at once, so only one frame is
    held in memory; the renames happen when the block ends without an error.
    Paths not written in the block are left alone.
    """
    paths = [Path(p) for p in paths]
    formats = {p: image_format(p) for p in paths}
    probed: set[Path] = set()
    for p in paths:
        if p.is_dir():
            raise OutputError(f"@{p}@ is a directory; give a file name.")
        if p.parent not in probed:  # one write probe per directory, not per frame
            check_writable(p)
            probed.add(p.parent)
    with atomic_outputs(paths) as temps:

        def write(path: Path, pixels: np.ndarray) -> None:
            path = Path(path)
            if path not in temps:
                raise ValueError(f"{path} is not one of the sequence's paths")
            _write(temps[path], pixels, formats[path], path)

        yield write


def read_image(path: str | os.PathLike) -> np.ndarray:
    """(H, W, C) float32: PNG values scaled to [0, 1] (still sRGB-encoded), EXR values as stored."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"@{p}@: no such image file.")
    inp = oiio.ImageInput.open(str(p))
    if inp is None:
        raise InputError(f"@{p}@: cannot be read as an image ({oiio.geterror()}).")
    try:
        data = inp.read_image(oiio.FLOAT)
    finally:
        inp.close()
    if data is None:
        raise InputError(f"@{p}@: reading the pixels failed.")
    a = np.asarray(data, dtype=np.float32)
    return a if a.ndim == 3 else a[:, :, None]
