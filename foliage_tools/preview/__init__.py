"""The previewer: rasterise a tree scene with moderngl, shaded with the project's leaf optics.

Modules: :mod:`camera` (orbit and USD cameras), :mod:`optics` (leaf, wood and
ground parameters), :mod:`renderer` (GL context, shadow map, drawing;
shaders in ``shaders/``), :mod:`tonemap` (Reinhard) and :mod:`compare`
(labelled side-by-side and false-colour error images). Pure numerics and GL:
no USD, no files (those are in :mod:`foliage_tools.scene`).
"""
