"""Comparison images: labelled panels side by side, and false-colour error against a reference.

Panels are float RGB arrays (H, W, 3) in whatever space the caller uses
(display-linear for PNG output, radiance for EXR); labels are drawn in a
header strip above each panel with matplotlib's text rendering (Agg), white on
dark grey, so they never cover the picture.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from foliage_tools.preview.tonemap import luminance, srgb_decode

HEADER_BACKGROUND = 0.02
"""Display-linear grey of the label strip."""
SEPARATOR = 2
"""Pixels of background between panels."""
NO_DATA = (0.05, 0.05, 0.05)
"""Display-linear colour of error-image pixels where the reference shows no tree."""


def header_height(panel_height: int) -> int:
    """Label strip height: readable at 256 px, not wasteful at 2048 px."""
    return int(np.clip(round(panel_height * 0.06), 16, 48))


@lru_cache(maxsize=64)
def _text_mask(text: str, width: int, height: int) -> np.ndarray:
    """(height, width) float32 coverage in [0, 1] of ``text``, left-aligned and vertically centred."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    dpi = 100
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, facecolor="black")
    canvas = FigureCanvasAgg(fig)
    # font size in points: 60 % of the strip height in pixels (1 pt = dpi/72 px)
    fig.text(6 / width, 0.5, text, color="white", fontsize=0.6 * height * 72 / dpi, va="center", ha="left", family="DejaVu Sans")
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    return (rgba[:height, :width, 0].astype(np.float32) / 255.0).copy()


def label(panel: np.ndarray, text: str, *, ink: float = 1.0) -> np.ndarray:
    """``panel`` with a header strip holding ``text`` on top: (H + h, W, 3) float32."""
    h, w = panel.shape[:2]
    hh = header_height(h)
    mask = _text_mask(text, w, hh)[..., None]
    strip = HEADER_BACKGROUND * (1.0 - mask) + ink * mask
    return np.concatenate([np.broadcast_to(strip, (hh, w, 3)).astype(np.float32), panel[..., :3].astype(np.float32)])


def side_by_side(rows: list[list[np.ndarray]], labels: list[list[str]], *, ink: float = 1.0) -> np.ndarray:
    """A grid of labelled panels (all the same size), rows top to bottom, separated by thin gaps."""
    if not rows or not rows[0]:
        raise ValueError("nothing to compose")
    shape = rows[0][0].shape[:2]
    if any(p.shape[:2] != shape for row in rows for p in row):
        raise ValueError("all panels must have the same size")
    ncols = max(len(r) for r in rows)
    labelled = []
    for row, names in zip(rows, labels):
        cells = [label(p, t, ink=ink) for p, t in zip(row, names)]
        blank = np.full_like(cells[0], HEADER_BACKGROUND)
        cells += [blank] * (ncols - len(cells))
        gap = np.full((cells[0].shape[0], SEPARATOR, 3), HEADER_BACKGROUND, np.float32)
        line = [cells[0]]
        for c in cells[1:]:
            line += [gap, c]
        labelled.append(np.concatenate(line, axis=1))
    out = [labelled[0]]
    for r in labelled[1:]:
        out += [np.full((SEPARATOR, r.shape[1], 3), HEADER_BACKGROUND, np.float32), r]
    return np.concatenate(out, axis=0)


def relative_error(test: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(H, W) signed relative luminance error (test − ref) / ref where ``mask`` > 0.5 and ref > 0, NaN elsewhere."""
    yt, yr = luminance(test), luminance(reference)
    ok = (np.asarray(mask) > 0.5) & (yr > 0)
    out = np.full(yr.shape, np.nan)
    out[ok] = (yt[ok] - yr[ok]) / yr[ok]
    return out


def rel_rms(test: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """DESIGN.md's relative RMS, sqrt(Σ(x−r)²/Σr²), over the luminance of the pixels where ``mask`` > 0.5."""
    m = np.asarray(mask) > 0.5
    yt, yr = luminance(test)[m], luminance(reference)[m]
    den = float(np.sum(yr**2))
    return float(np.sqrt(np.sum((yt - yr) ** 2) / den)) if den > 0 else float("nan")


def false_colour(error: np.ndarray, *, scale: float = 0.5, colormap: str = "RdBu_r") -> np.ndarray:
    """(H, W, 3) display-linear image of a signed error: blue too dark, red too bright, white exact.

    ``scale`` is the error shown at full saturation (0.5 = ±50 %); NaN pixels
    (no data) are dark grey.
    """
    import matplotlib

    if not scale > 0:
        raise ValueError(f"scale must be positive, got {scale}")
    cmap = matplotlib.colormaps[colormap]
    t = np.clip(np.nan_to_num(error, nan=0.0) / scale * 0.5 + 0.5, 0.0, 1.0)
    rgb = srgb_decode(cmap(t)[..., :3])  # colormaps are sRGB-encoded
    rgb[np.isnan(error)] = NO_DATA
    return rgb.astype(np.float32)
