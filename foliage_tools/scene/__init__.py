"""The only package that talks to USD (``pxr``) and OpenVDB (``pyopenvdb``).

``model`` holds the plain dataclasses the rest of the code works on; ``read``,
``write``, ``vdb`` and ``validate`` convert between them and files. Importing
this package does not import ``pxr``: the I/O modules do, when used.
"""

from foliage_tools.scene.model import Instance, Leaves, Light, MeshPart, Prototype, Scene

__all__ = ["Instance", "Leaves", "Light", "MeshPart", "Prototype", "Scene"]
