"""Check a JSON value against the ``TypedDict`` that declares it (``foliage_tools.pipeline.stats``).

mypy checks the keys the code writes and the CLI reads; this checks, at run time, that what a command actually
printed has exactly the declared keys (required ones present, none undeclared) and values of the declared kinds.
"""

from __future__ import annotations

import types
import typing
from collections.abc import Mapping
from typing import Any, get_args, get_origin, get_type_hints, is_typeddict

from foliage_tools.pipeline import stats as S

#: Each command's stats type.
STATS_TYPES: dict[str, Any] = {
    "inspect": S.InspectStats, "validate": S.ValidateStats, "plan": S.PlanStats, "density": S.DensityStats,
    "smax": S.SmaxStats, "spp": S.SppStats, "lb": S.LBStats, "reference": S.ReferenceStats, "bench": S.BenchStats,
    "preview": S.PreviewStats, "bake": S.BakeStats, "batch": S.BatchStats, "import": S.ImportStats,
}


def problems(value: Any, tp: Any, where: str = "stats") -> list[str]:
    """Every place where ``value`` is not of type ``tp``, as ``where.key[i]: what``; empty when it is."""
    if tp is Any:
        return []
    if is_typeddict(tp):
        if not isinstance(value, dict):
            return [f"{where}: {type(value).__name__}, expected an object ({tp.__name__})"]
        hints = get_type_hints(tp)
        out = [f"{where}: missing key {k!r} ({tp.__name__})" for k in sorted(tp.__required_keys__ - value.keys())]
        out += [f"{where}: key {k!r} is not declared in {tp.__name__}" for k in sorted(value.keys() - hints.keys())]
        for k in value.keys() & hints.keys():
            out += problems(value[k], hints[k], f"{where}.{k}")
        return out
    origin, args = get_origin(tp), get_args(tp)
    if origin in (types.UnionType, typing.Union):
        each = [problems(value, a, where) for a in args]
        return [] if any(not p for p in each) else [f"{where}: {value!r:.60} is none of {tp}"]
    if tp is None or tp is type(None):
        return [] if value is None else [f"{where}: {value!r:.60}, expected null"]
    if origin is list:
        if not isinstance(value, list):
            return [f"{where}: {type(value).__name__}, expected a list"]
        return [p for i, v in enumerate(value) for p in problems(v, args[0], f"{where}[{i}]")]
    if origin in (dict, Mapping):
        if not isinstance(value, dict):
            return [f"{where}: {type(value).__name__}, expected an object"]
        return [p for k, v in value.items() for p in problems(v, args[1], f"{where}.{k}")]
    if tp is bool:
        return [] if isinstance(value, bool) else [f"{where}: {value!r:.60}, expected a bool"]
    if tp is int:
        return [] if isinstance(value, int) and not isinstance(value, bool) else [f"{where}: {value!r:.60}, expected an int"]
    if tp is float:  # JSON writes 2.0 as 2
        return [] if isinstance(value, (int, float)) and not isinstance(value, bool) else [f"{where}: {value!r:.60}, expected a number"]
    if tp is str:
        return [] if isinstance(value, str) else [f"{where}: {value!r:.60}, expected a string"]
    raise TypeError(f"{where}: typed_json does not know the type {tp!r}")


def assert_typed_stats(report: dict) -> None:
    """``report`` (a parsed ``--json`` object) has the stats its command's ``TypedDict`` declares."""
    found = problems(report["stats"], STATS_TYPES[report["command"]])
    assert not found, "\n".join(found)
