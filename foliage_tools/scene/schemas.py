"""Register the codeless foliage API schemas (``schemas/usd``) with USD's plugin system.

USD must learn about the schemas before the first stage is opened, or it
silently treats them as unknown: every module that opens stages calls
:func:`register` first.
"""

from __future__ import annotations

import functools
from importlib import resources
from pathlib import Path


LEAF_API = "FoliageLeafAPI"
LIGHTING_API = "FoliageLightingAPI"
ENVELOPE_API = "FoliageEnvelopeAPI"


def schema_dir() -> Path:
    """``schemas/usd`` of the repository, installed as the ``foliage_tools.schemas`` package."""
    path = Path(str(resources.files("foliage_tools.schemas") / "usd"))
    if not (path / "plugInfo.json").is_file():
        raise RuntimeError(f"foliage USD schemas missing: no plugInfo.json in {path}; reinstall foliage-tools")
    return path


@functools.cache
def register() -> None:
    """Register the plugin once per process (idempotent)."""
    from pxr import Plug

    Plug.Registry().RegisterPlugins(str(schema_dir()))
