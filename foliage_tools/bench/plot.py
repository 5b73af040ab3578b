"""The speed-vs-error plot of ``foliage bench`` (matplotlib, written atomically)."""

from __future__ import annotations

from pathlib import Path

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


def write_plot(path: Path, stats: dict, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    check_plot_path(path)
    fig, ax = plt.subplots(figsize=(6, 4.5), dpi=120)
    for m in stats["methods"]:
        if not m["available"] or m["rel_rms_total"] is None or m["rel_rms_scattered"] is None:
            continue
        for key, marker, label in (("rel_rms_total", "o", "total"), ("rel_rms_scattered", "s", "scattered")):
            ax.loglog(m["seconds"], max(m[key], 1e-6), marker, color="C0" if key == "rel_rms_total" else "C1")
        ax.annotate(m["name"], (m["seconds"], max(m["rel_rms_total"], 1e-6)), textcoords="offset points", xytext=(5, 5))
    ref = stats["reference"]
    ax.axhline(ref["noise_rel"], color="grey", ls="--", lw=1, label=f"reference noise (E_scattered), {ref['paths']:,} paths")
    ax.axhline(ref["noise_rel_total"], color="grey", ls=":", lw=1, label="reference noise (total)")
    ax.plot([], [], "o", color="C0", label="rel. RMS error, total")
    ax.plot([], [], "s", color="C1", label="rel. RMS error, E_scattered")
    ax.set_xlabel("seconds")
    ax.set_ylabel("relative RMS error vs Monte Carlo")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    with atomic_outputs([path]) as temps:
        fig.savefig(temps[path], format=path.suffix.lstrip(".").lower())
    plt.close(fig)
    return path
