"""Which way a tree stands, from its geometry alone: ``foliage import --up-axis auto``, and the warning of
``inspect`` and ``validate`` when a stage's ``upAxis`` would lay its tree on its side.

Along its up axis a tree's lowest points are wood (the trunk's base) and its highest are leaves: the leaves' lowest
point lies well above the tree's, their highest at the tree's top. Across it, a crown reaches as far as the wood on
both sides, so neither gap opens. Failing that (no wood, or none below the crown), a clearly tallest extent decides,
which cannot tell up from down.
"""

from __future__ import annotations

import numpy as np

#: The trunk decides when the leaves begin at least this share of the tree's extent above its lowest point along one
#: axis (and reach its top), and no other axis shows such a gap; 5 %: the three third-party test trees show 15-30 %
#: along their up axis and 0 % across it.
TRUNK_GAP = 0.05
#: Without a trunk to go by, the tallest extent decides when it is this much longer than each other one.
TALLER = 1.2

_AXES = "XYZ"


def stands_along(points: np.ndarray, leaf_points: np.ndarray | None, *, trunk_only: bool = False
                 ) -> tuple[str | None, str]:
    """The axis the tree stands along, ``"+X"`` .. ``"-Z"``, and why; None and why when it cannot tell.

    ``points``: (n, 3) every point of the tree (wood and leaves); ``leaf_points``: the leaves' (None or empty: no
    leaves told apart). ``trunk_only``: decide by the trunk alone, never by the tallest extent (a wide crown is
    wider than tall: a warning must not rest on that).
    """
    points = np.asarray(points, dtype=float)
    if not len(points):
        return None, "it has no points"
    lo, hi = points.min(axis=0), points.max(axis=0)
    extent = hi - lo
    if leaf_points is not None and 0 < len(leaf_points) < len(points):
        leaf = np.asarray(leaf_points, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            below = np.where(extent > 0, (leaf.min(axis=0) - lo) / extent, 0.0)  # wood under the lowest leaf
            above = np.where(extent > 0, (hi - leaf.max(axis=0)) / extent, 0.0)  # wood over the highest leaf
        score = np.concatenate([below - above, above - below])  # +X, +Y, +Z, -X, -Y, -Z
        best = int(np.argmax(score))
        rivals = np.delete(score, [best, (best + 3) % 6])
        if score[best] >= TRUNK_GAP and not np.any(rivals >= TRUNK_GAP):
            gap = below[best % 3] if best < 3 else above[best % 3]
            return (("+" if best < 3 else "-") + _AXES[best % 3],
                    f"its wood reaches {100 * gap:.0f} % of its {_AXES[best % 3]} extent beyond its leaves")
    if trunk_only:
        return None, "no trunk below the crown shows which way is up"
    order = np.argsort(extent)[::-1]
    if extent[order[1]] > 0 and extent[order[0]] >= TALLER * extent[order[1]]:
        axis = _AXES[int(order[0])]
        return f"+{axis}", (f"it is {extent[order[0]] / extent[order[1]]:.1f}x as tall along {axis} as across "
                            "(no trunk below the crown to tell up from down)")
    return None, "neither a trunk below the crown nor a clearly tallest extent shows which way is up"
