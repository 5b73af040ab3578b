"""foliage-tools: bake the light that scatters through foliage.

Layers (arrows only downward): ``cli`` -> ``foliage_tools.pipeline`` ->
numerical core (``geometry``, ``lighting``: numpy/numba/scipy only). All
``pxr``/``pyopenvdb`` code lives in ``foliage_tools.scene``.
"""

__version__ = "0.1.0"
