"""The methods ``foliage bench`` compares, discovered through a registry.

A method module in ``foliage_tools/bench/methods/`` calls :func:`register`
at import; :func:`methods` imports every module there, so a method that lands
later appears in ``bench`` without editing it. Methods the design lists but
that have not landed are reported as unavailable (``PLANNED``).
"""

from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass, field
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from foliage_tools.geometry.sun import Sun
from foliage_tools.lighting.optics import LeafOptics
from foliage_tools.scene.model import Scene

if TYPE_CHECKING:
    from foliage_tools.pipeline.direct import DirectBake


@dataclass(frozen=True)
class BenchContext:
    """What every method gets: the scene, the sun (world space), the optics."""

    scene: Scene
    sun: Sun
    optics: LeafOptics
    warnings: list[str] = field(default_factory=list)
    direct: "DirectBake | None" = None
    """The exact direct light, traced once for all methods (its seconds are already in every method's)."""


@dataclass(frozen=True)
class MethodOutput:
    """Per prototype (index = Scene.prototypes), per-leaf (L, 3) RGB irradiance (DESIGN.md section 3)."""

    e_direct: dict[int, np.ndarray]
    e_scattered: dict[int, np.ndarray]
    stats: Mapping[str, Any] = field(default_factory=dict)
    scattered_per_instance_leaf: np.ndarray | None = None
    """(L_world, 3) E_scattered of every leaf of every instance, for a method that traced them all (the
    gathers); None: the prototype's values serve every instance (and the forest lattice scales them)."""


@dataclass(frozen=True)
class BenchMethod:
    name: str
    description: str
    run: Callable[[BenchContext], MethodOutput] | None
    """None for a planned method that has not landed."""

    @property
    def available(self) -> bool:
        return self.run is not None


#: Methods of DESIGN.md that ``bench`` reports as unavailable until they land (name -> why).
#: Every method of DESIGN.md section 3 has landed; keep this for the next one.
PLANNED: dict[str, str] = {}

_REGISTRY: dict[str, BenchMethod] = {}


def register(name: str, description: str) -> Callable:
    """Decorator: ``@register("smax", "...")`` on a ``run(ctx) -> MethodOutput`` function."""

    def deco(fn: Callable[[BenchContext], MethodOutput]) -> Callable[[BenchContext], MethodOutput]:
        if name in _REGISTRY:
            raise ValueError(f"bench method {name!r} registered twice")
        _REGISTRY[name] = BenchMethod(name, description, fn)
        return fn

    return deco


def in_family(request: str, name: str) -> bool:
    """Whether ``--methods`` entry ``request`` selects method ``name``: the name itself, or a family, the name
    before a ``-`` (``lb`` selects ``lb-32``, ``lb-64`` and ``lb-64-lattice1``; not ``lb+gather``)."""
    return name == request or name.startswith(request + "-")


def selects(request: str, names: list[str]) -> list[str]:
    """The methods of ``names`` that ``--methods`` entry ``request`` selects: a method's own name selects it alone;
    ``NAME*`` selects the family (NAME and its variants, ``in_family``); a family name that is no method's name
    (``lb``) selects the family too. ``smax`` is the method smax, ``smax*`` is smax, smax-leaves and smax-paper."""
    if request.endswith("*"):
        return [n for n in names if in_family(request[:-1], n)]
    if request in names:
        return [request]
    return [n for n in names if in_family(request, n)]


def families(names: list[str]) -> dict[str, list[str]]:
    """Each family of ``names`` (the part before the first ``-`` of a variant) -> the methods it selects."""
    heads = sorted({n.split("-")[0] for n in names if "-" in n})
    return {head: [n for n in names if in_family(head, n)] for head in heads}


def methods() -> list[BenchMethod]:
    """Every registered method, then the planned ones not yet registered (unavailable)."""
    from foliage_tools.bench import methods as pkg

    for info in pkgutil.iter_modules(pkg.__path__):
        importlib.import_module(f"{pkg.__name__}.{info.name}")
    found = sorted(_REGISTRY.values(), key=lambda m: m.name)
    planned = [
        BenchMethod(name, why, None)
        for name, why in PLANNED.items()
        if not any(m.name == name or m.name.startswith(name + "-") for m in found)
    ]
    return found + planned
