"""``foliage import``: a mesh file (OBJ, PLY, glTF/GLB, ...) -> a USD tree asset the bakes read.

Reading and clean-ups are pymeshlab's (``scene.meshfile``); the USD layout is
``scene.asset``'s. Leaves vs wood: a part whose name (OBJ object/group or
material, glTF mesh) matches ``leaf_pattern`` holds leaves, the rest is wood;
``all_leaves`` makes every part leaves (a file of leaf cards only).

The pattern is matched by RE2 (google-re2), whose time is linear in the name's length: a pattern such as
``(a+)+$``, which backtracks for ever in Python's ``re`` on a long name, is matched at once. RE2 has no
look-arounds or backreferences.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from foliage_tools.errors import UsageError
from foliage_tools.geometry import upright
from foliage_tools.pipeline.report import Progress, Report, Silent
from foliage_tools.scene.meshfile import CleanOptions
from foliage_tools.pipeline.stats import ImportStats

#: The names that mean leaves, as in scene.read (DESIGN.md section 3).
DEFAULT_LEAF_PATTERN = r"leaf|leaves|foliage|needle"


def stands_along(parts: list[Any]) -> tuple[str | None, str]:
    """:func:`foliage_tools.geometry.upright.stands_along` of a model file's parts."""
    points = [p.points for p in parts if len(p.points)]
    leaves = [p.points for p in parts if p.is_leaf and len(p.points)]
    if not points:
        return None, "the model has no points"
    return upright.stands_along(np.concatenate(points), np.concatenate(leaves) if leaves else None)


#: The file formats whose specification fixes the up axis (glTF 2.0: +Y up).
Y_UP_FORMATS = (".gltf", ".glb")


@dataclass(frozen=True)
class ImportParams:
    up_axis: str = "auto"
    """The model's up axis, authored as the stage's ``upAxis`` (geometry is not rotated): ``Y``, ``Z`` or ``auto``
    (:func:`stands_along`: the trunk at the bottom, else the tallest extent; glTF is Y-up by its spec). OBJ and PLY
    have no convention: Blender exports Y-up, many tree libraries Z-up."""
    meters_per_unit: float = 1.0
    """Length of one model unit in metres, authored as ``metersPerUnit`` (glTF is metres by its spec; 0.01 for cm)."""
    leaf_pattern: str = DEFAULT_LEAF_PATTERN
    """Regular expression (case-insensitive) on part names: a match holds leaves."""
    all_leaves: bool = False
    """Every part holds leaves (a file of leaf cards only)."""
    clean: CleanOptions = field(default_factory=CleanOptions)

    def __post_init__(self) -> None:
        if self.up_axis.upper() not in ("Y", "Z", "AUTO"):
            raise UsageError(f"--up-axis {self.up_axis!r}: USD stages are Y-up or Z-up (or give auto).")
        if not (np.isfinite(self.meters_per_unit) and self.meters_per_unit > 0):
            raise UsageError(f"--meters-per-unit {self.meters_per_unit}: must be a finite length > 0.")
        leaf_matcher(self.leaf_pattern)


def leaf_matcher(pattern: str) -> Any:
    """``pattern`` compiled by RE2, case-insensitive: :class:`UsageError` naming it when RE2 cannot read it."""
    import re2

    options = re2.Options()
    options.case_sensitive = False
    options.log_errors = False  # the error is ours to say, once
    try:
        return re2.compile(pattern, options)
    except re2.error as exc:
        why = exc.args[0].decode("utf-8", "replace") if exc.args and isinstance(exc.args[0], bytes) else str(exc)
        raise UsageError(f"--leaves {pattern!r} is not a regular expression RE2 reads ({why}); it takes Python's "
                         "syntax but for look-arounds and backreferences, which keeps a match linear in the name's "
                         "length.") from None


def run_import(path: Path, out: Path, params: ImportParams, *, progress: Progress | None = None) -> Report[ImportStats]:
    from foliage_tools.scene.asset import write_tree_asset
    from foliage_tools.scene.atomic import refuse_link_loop
    from foliage_tools.scene.dependencies import require_file
    from foliage_tools.scene.meshfile import read_parts

    progress = progress or Silent()
    report: Report[ImportStats] = Report(command="import", inputs=[str(path)])
    path, out = Path(path), Path(out)
    require_file(path, "Give the mesh file to import.")  # a loop, FIFO or device named for what it is, never opened
    refuse_link_loop(out)
    if out.resolve() == path.resolve():
        raise UsageError(f"@{out}@ is the input file; choose another output (inputs are never modified).")
    progress.step(f"reading {path}")
    pattern = leaf_matcher(".*" if params.all_leaves else params.leaf_pattern)
    parts, warnings = read_parts(path, leaf_pattern=pattern, options=params.clean)
    report.warnings += warnings
    if not any(p.is_leaf for p in parts):
        names = ", ".join(repr(p.name) for p in parts[:8])
        report.warnings.append(
            f"@{path}@: no part's name matches {params.leaf_pattern!r} (parts: {names}), so everything is wood and the "
            "bakes will refuse it; name the leaf parts, or pass --leaves PATTERN or --all-leaves.")
    up_axis = _up_axis(path, parts, params.up_axis.upper(), report.warnings)
    progress.step(f"writing {out}")
    doc = f"Imported from {path.name} by `foliage import` (pymeshlab; UVs, normals and textures not carried)."
    prims = write_tree_asset(out, parts, up_axis=up_axis, meters_per_unit=params.meters_per_unit, doc=doc)
    report.outputs = [str(out)]
    report.stats = {
        "up_axis": up_axis,
        "meters_per_unit": params.meters_per_unit,
        "parts": [
            {"prim": prim, "name": p.name, "material": p.material, "leaf": p.is_leaf, "faces_read": p.faces_read,
             "triangles": int(len(p.triangles)), "points": int(len(p.points))}
            for prim, p in zip(prims, parts)
        ],
    }
    return report.finish()


def _up_axis(path: Path, parts: list[Any], asked: str, warnings: list[str]) -> str:
    """The ``upAxis`` to author: ``asked`` (``Y``, ``Z``), or for ``AUTO`` the one the geometry shows
    (:func:`stands_along`; glTF's Y by its spec). A tree that would lie on its side or stand on its head is warned
    about, naming the axis it stands along and what to give."""
    found, why = stands_along(parts)
    spec = "Y" if path.suffix.lower() in Y_UP_FORMATS else None
    if asked == "AUTO":
        if spec is not None:
            chosen = spec
        elif found is not None and found[1] in "YZ":
            chosen = found[1]
        else:
            chosen = "Y"
            if found is None:
                warnings.append(f"@{path}@: cannot tell which way is up ({why}), so upAxis is Y; if the tree lies on "
                                "its side in `foliage preview`, import it again with --up-axis Z.")
    else:
        chosen = asked
    if found is not None and found != f"+{chosen}":
        fix = (f"import it again with --up-axis {found[1]}" if found[0] == "+" and found[1] in "YZ" else
               "turn it upright in a DCC (upAxis cannot say " + found + ")")
        warnings.append(f"@{path}@: the tree stands along {found} ({why}), but upAxis is {chosen}, so it would "
                        f"{'stand on its head' if found[1] == chosen else 'lie on its side'}: {fix}.")
    return chosen
