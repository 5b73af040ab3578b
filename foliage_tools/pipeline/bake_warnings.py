"""The warnings of a bake's stages as one list: each said once, in the order the stages first gave it.

Every stage of ``foliage bake`` reads the same input, so several give the same warning (a native-instance
prototype: each stage could not store its own per-leaf primvars on it). Printed once per stage, they buried
the rest. A text that several stages gave is kept once, prefixed with all their names (``smax, spp: ...``);
the native-instance warnings of one prototype, which differ only in what each stage could not store, become
one that lists it all.
"""

from __future__ import annotations

import re

from foliage_tools.pipeline.leafdata import NATIVE_INSTANCE_REASON

_NATIVE = re.compile(r"prototype <(?P<path>[^>]*)> is a native instance: (?P<what>.+?) "
                     + re.escape(NATIVE_INSTANCE_REASON) + r"(?P<more>.*)$", re.S)


def merge(stage_warnings: list[tuple[str, list[str]]]) -> list[str]:
    """``[(stage, its warnings), ...]`` in stage order -> ``"stage[, stage...]: text"``, each text once."""
    order: list[str] = []  # keys in order of first appearance
    stages: dict[str, list[str]] = {}
    native: dict[str, dict] = {}  # key -> what each stage could not store, and the stages' extra sentences
    for stage, warnings in stage_warnings:
        for text in warnings:
            found = _NATIVE.match(text)
            key = f"native <{found['path']}>" if found else text
            if key not in stages:
                order.append(key)
                stages[key] = []
                if found:
                    native[key] = {"path": found["path"], "what": [], "more": []}
            if stage not in stages[key]:
                stages[key].append(stage)
            if found:
                for part, value in (("what", found["what"]), ("more", found["more"].strip())):
                    if value and value not in native[key][part]:
                        native[key][part].append(value)
    return [f"{', '.join(stages[key])}: {_native_text(native[key]) if key in native else key}" for key in order]


def _native_text(n: dict) -> str:
    what = n["what"]
    listed = what[0] if len(what) == 1 else f"{', '.join(what[:-1])} and {what[-1]}"
    return " ".join([f"prototype <{n['path']}> is a native instance: {listed} {NATIVE_INSTANCE_REASON}", *n["more"]])
