"""The previewer: rasterise a tree scene with moderngl, shaded with the project's leaf optics.

Modules: :mod:`camera` (orbit and USD cameras), :mod:`optics` (leaf, wood and
ground parameters), :mod:`draw_model` (what is drawn: meshes, instances, sun
and sky, ground, frames; no GL), :mod:`renderer` (sky, shadow and main passes;
shaders in ``shaders/``), :mod:`gl` (GL context, shader sources, buffer
layouts), :mod:`tonemap` (Reinhard) and :mod:`compare`
(labelled side-by-side and false-colour error images). Pure numerics and GL:
no USD, no files (those are in :mod:`foliage_tools.scene`).
"""
