"""The speed-vs-error plot of ``foliage bench`` (matplotlib, written atomically)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from foliage_tools.errors import OutputError
from foliage_tools.scene.atomic import atomic_outputs, check_writable


def check_plot_path(path: Path) -> None:
    """Refuse, before any work, a plot path whose directory is not writable or whose format matplotlib cannot write."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    path = Path(path)
    formats = Figure().canvas.get_supported_filetypes()
    fmt = path.suffix.lstrip(".").lower()
    if fmt not in formats:
        raise OutputError(f"@{path}@: matplotlib cannot write {fmt or 'files without an extension'}; use one of "
                          f"{', '.join('.' + f for f in sorted(formats))} (.png, .svg or .pdf are usual).")
    check_writable(path)


def write_plot(path: Path, stats: Mapping[str, Any], title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    check_plot_path(path)
    fig, ax = plt.subplots(figsize=(7, 4.8), dpi=120)
    # one colour per method, named in the legend (labels next to the points overlapped whenever two
    # methods had about the same seconds and error); a vertical line joins its two errors
    shown = [m for m in stats["methods"]
             if m["available"] and m["rel_rms_total"] is not None and m["rel_rms_scattered"] is not None]
    # tab20: a colour of its own for each of the bench's 20 methods (C0-C9 repeated from the eleventh on)
    palette = plt.get_cmap("tab20")
    for k, m in enumerate(shown):
        colour = palette(k % palette.N)
        total, scattered = max(m["rel_rms_total"], 1e-6), max(m["rel_rms_scattered"], 1e-6)
        ax.loglog([m["seconds"]] * 2, [total, scattered], "-", color=colour, lw=0.8, alpha=0.6)
        ax.loglog(m["seconds"], total, "o", color=colour, label=m["name"])
        ax.loglog(m["seconds"], scattered, "s", color=colour, mfc="none")
    ref = stats["reference"]
    ax.axhline(ref["noise_rel"], color="grey", ls="--", lw=1, label=f"reference noise, E_scattered ({ref['paths']:,} paths)")
    ax.axhline(ref["noise_rel_total"], color="grey", ls=":", lw=1, label="reference noise, total")
    ax.plot([], [], "o", color="k", label="total (exact direct + scattered)")
    ax.plot([], [], "s", color="k", mfc="none", label="E_scattered")
    from matplotlib.ticker import FuncFormatter, LogLocator

    # plain short labels at 1, 2, 5 x 10^k (matplotlib's 4x10^-1-style minor labels overlapped on narrow ranges)
    short = FuncFormatter(lambda v, _: f"{v:g}")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(LogLocator(base=10.0))
        axis.set_minor_locator(LogLocator(base=10.0, subs=(2.0, 5.0)))
        axis.set_major_formatter(short)
        axis.set_minor_formatter(short)
    ax.margins(x=0.15, y=0.1)
    ax.set_xlabel("seconds")
    ax.set_ylabel("relative RMS error vs Monte Carlo")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5), borderaxespad=0.0)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    with atomic_outputs([path]) as temps:
        fig.savefig(temps[path], format=path.suffix.lstrip(".").lower())
    plt.close(fig)
    return path
