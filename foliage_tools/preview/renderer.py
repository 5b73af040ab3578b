"""Rasterise a tree scene with moderngl: headless GL context, programs, shadow map, drawing.

A frame is made of these passes:

1. **Sky pass** (once per scene) -- orthographic depth maps of the trees seen
   from up to 16 directions spread evenly over the sky, tiled in one texture;
   the shader uses them for the fraction of the sky each point sees.
2. **Shadow pass** -- an orthographic depth map seen from the sun, fitted to
   the world bounds of the tree geometry, with both faces of every triangle
   (leaves are thin cards). Re-drawn only when the sun moves.
3. **Main pass** -- leaves (two-sided: reflection, transmission, glossy lobe),
   wood (opaque Lambertian) and the optional ground plane into a float
   framebuffer holding linear radiance and a tree mask, read back as numpy
   arrays.

Antialiasing is supersampling: the main pass renders k×k samples per pixel
and the image is box-filtered down on read-back. On Mesa's llvmpipe this is
about twice as fast as 4× MSAA at equal sample count (measured:
``docs/preview_notes.md``), shades every sample, and gives the same result
on every driver.

Geometry is uploaded once per :class:`DrawScene`: one vertex buffer per
prototype and material, and one buffer of per-instance matrices, so a forest
costs one instanced draw call per prototype and material.

Shading is in ``shaders/*.glsl`` (equations cited there); the optics come
from :mod:`foliage_tools.preview.optics`. Baked methods bring E_scattered per
vertex; the ``smax`` method brings s_max per vertex and τ per prototype, and
``shaders/boulanger.glsl`` evaluates Boulanger's model for the current sun in
the vertex shader (:meth:`Renderer.smax_irradiance` reads every term of it
back by transform feedback). This module knows nothing of USD or
files. What is drawn (:class:`DrawScene`, :class:`Lighting`, :class:`Ground`,
:class:`Frame`) is GL-free, in :mod:`foliage_tools.preview.draw_model`, and
this module re-exports those names; the context, shader sources and buffer
layouts are in :mod:`foliage_tools.preview.gl`. What stays here (~660 lines,
above the ~600 the project aims for) is one class, :class:`Renderer`, whose
passes share the GL objects it owns (programs, buffers, the shadow and sky
textures, the render targets): split into modules they would hand that state
to each other, which is the coupling the split is meant to remove.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from foliage_tools.errors import UsageError
from foliage_tools.preview.camera import Camera, bounds_corners, look_at, orthographic
from foliage_tools.preview.draw_model import (
    RGB,
    DrawMesh,
    DrawScene,
    Frame,
    Ground,
    Lighting,
    face_normals,
    sky_directions,
)
# the draw model's names stay importable from here (DrawPrototype is not used below)
from foliage_tools.preview.draw_model import DrawPrototype as DrawPrototype
from foliage_tools.preview.gl import INSTANCE_LAYOUT, _box_filter, _instance_data, _mat, _padded, _shader, create_context
from foliage_tools.preview.optics import SurfaceOptics

if TYPE_CHECKING:  # moderngl is imported where the context is made (create_context); here only for its types
    import moderngl

MAX_SKY_SAMPLES = 16
"""Sky directions whose occlusion is tested (``MAX_SKY`` in ``shaders/sky.glsl``)."""
SKY_TILE = 512
"""Texels per side of each sky direction's depth map."""
SKY_CACHE_WIDTH = 4096
"""Texels per row of the per-vertex sky-visibility textures."""
SAMPLES = (1, 4, 9, 16)
"""Samples per pixel: a k×k grid of supersamples (k = 1..4), box-filtered down."""


@dataclass
class _Draw:
    """GPU buffers of one :class:`DrawMesh` and the instances of its prototype."""

    key: tuple[int, int]
    """(prototype index, mesh index)."""
    leaf: bool
    positions: moderngl.Buffer
    normals: moderngl.Buffer
    instances: moderngl.Buffer
    instance_count: int
    indirect: dict[str, moderngl.Buffer]
    triangle_count: int = 0
    smax: moderngl.Buffer | None = None
    """(3T, 8) float32 buffer of s_max per vertex (the ``smax`` method), or None."""
    tau: float = 0.0
    omega: np.ndarray | None = None
    """(8, 3) eq. (5.28) directions in the prototype's frame."""
    sky_cache: moderngl.Texture | None = None
    """RG float texture: sky visibility (front, back) per vertex and instance, written once by the sky pass."""
    sky_cache_width: int = 1
    lb_tex: moderngl.Texture | None = None
    """RGB float texture of the 18 LB relighting bases per vertex (texel vertex * 18 + k), or None."""
    lb_width: int = 1
    lb_inst: moderngl.Buffer | None = None
    """Per-instance (3 base indices, 3 barycentric weights) buffer, rewritten for each frame's sun."""
    transforms: np.ndarray | None = None
    """(N, 4, 4) world-from-prototype matrices of the instances (for the sun in each instance's frame)."""


class Renderer:
    """Owns a GL context and the GPU copies of one :class:`DrawScene`.

    Use as a context manager, or call :meth:`release`. One renderer can draw
    many frames (cameras, suns, methods) of the scene it was given.
    """

    def __init__(self, scene: DrawScene, *, samples: int = 4, shadow_size: int = 2048, sky_samples: int = 16) -> None:
        if not (0 <= sky_samples <= MAX_SKY_SAMPLES):
            raise UsageError(f"--sky-samples must be between 0 (no sky occlusion) and {MAX_SKY_SAMPLES}, got {sky_samples}.")
        if samples not in SAMPLES:
            raise UsageError(f"--samples must be one of {', '.join(map(str, SAMPLES))} (a k×k grid per pixel), got {samples}.")
        if not (256 <= shadow_size <= 8192):
            raise UsageError(f"--shadow-size must be between 256 and 8192 texels, got {shadow_size}.")
        self.scene = scene
        self.bounds = scene.bounds()
        self.ctx = create_context()
        self.samples = samples
        self.supersample = math.isqrt(samples)
        self.max_size = int(self.ctx.info.get("GL_MAX_RENDERBUFFER_SIZE", 8192) or 8192)
        self.max_texture = int(self.ctx.info.get("GL_MAX_TEXTURE_SIZE", 8192) or 8192)
        self.shadow_size = shadow_size
        self.renderer_name = str(self.ctx.info.get("GL_RENDERER", "unknown"))
        self._programs: dict[tuple[str, bool | str], moderngl.Program] = {}
        self._vaos: dict[tuple[Any, ...], moderngl.VertexArray] = {}
        self._buffers: list[moderngl.Buffer] = []
        self._lb_textures: list[moderngl.Texture] = []
        self._targets: list[moderngl.Renderbuffer | moderngl.Framebuffer] | None = None
        self._target_size: tuple[int, int] | None = None
        self._shadow_key: tuple | None = None
        self._upload()
        self._shadow_tex = self.ctx.depth_texture((shadow_size, shadow_size))
        self._shadow_tex.compare_func = "<="
        self._shadow_tex.repeat_x = self._shadow_tex.repeat_y = False
        self._shadow_fbo = self.ctx.framebuffer(depth_attachment=self._shadow_tex)
        self._light_vp = np.eye(4)
        self._texel_world = 0.0
        self._depth_range = 1.0
        self.sky_samples = sky_samples
        self._sky_dirs = sky_directions(sky_samples, np.asarray(scene.up, dtype=np.float64))
        self._sky_tiles = max(1, math.ceil(math.sqrt(sky_samples)))
        self._sky_tex = self.ctx.depth_texture((self._sky_tiles * SKY_TILE,) * 2)
        self._sky_tex.compare_func = "<="
        self._sky_tex.repeat_x = self._sky_tex.repeat_y = False
        self._sky_fbo = self.ctx.framebuffer(depth_attachment=self._sky_tex)
        self._sky_vps = np.tile(np.eye(4), (MAX_SKY_SAMPLES, 1, 1))
        self._sky_texel_world = 0.0
        self._sky_depth_bias = 0.0
        self._sky_done = False

    # -- resources --------------------------------------------------------------
    def _program(self, kind: str, indirect: bool | str = False):
        """``shadow`` (depth only), ``skycache``/``smaxfeedback`` (transform feedback), or the surfaces ``leaf``, ``wood``, ``ground``.

        ``indirect``: False, True (a baked E_scattered per vertex) or ``"smax"`` (Boulanger's
        model evaluated in the vertex shader from s_max per vertex).
        """
        key = (kind, indirect)
        if key not in self._programs:
            version = "#version 330 core\n"
            if kind == "shadow":
                vert = version + "#define DEPTH_ONLY\n" + _shader("sky.glsl") + _shader("scene.vert.glsl")
                self._programs[key] = self.ctx.program(vertex_shader=vert, fragment_shader=version + _shader("shadow.frag.glsl"))
            elif kind == "skycache":
                vert = version + _shader("sky.glsl") + _shader("sky_cache.vert.glsl")
                self._programs[key] = self.ctx.program(vertex_shader=vert, varyings=["o_sky"])
            elif kind == "smaxfeedback":
                vert = version + _shader("boulanger.glsl") + _shader("smax_feedback.vert.glsl")
                varyings = ["o_direct", "o_scattered_front", "o_scattered_back", "o_sky_front", "o_sky_back"]
                self._programs[key] = self.ctx.program(vertex_shader=vert, varyings=varyings)
            else:
                defines = version + ("#define HAS_INDIRECT\n" if indirect else "") + ("#define SMAX_MODEL\n" if indirect == "smax" else "")
                defines += "#define LB_RELIGHT\n" if indirect == "lb-relight" else ""
                model = _shader("boulanger.glsl") if indirect == "smax" else ""
                # the trees read their sky visibility from the per-scene cache; the ground computes its own
                cached = "#define SKY_CACHED\n" if kind != "ground" and self.sky_samples else ""
                vert = defines + cached + _shader("sky.glsl") + model + _shader("scene.vert.glsl")
                frag = defines + f"#define {kind.upper()}\n" + _shader("lighting.glsl") + _shader("surface.frag.glsl")
                self._programs[key] = self.ctx.program(vertex_shader=vert, fragment_shader=frag)
        return self._programs[key]

    def _buffer(self, data: np.ndarray):
        buf = self.ctx.buffer(np.ascontiguousarray(data, dtype=np.float32).tobytes())
        self._buffers.append(buf)
        return buf

    def _upload(self) -> None:
        self._draws: list[_Draw] = []
        for i, proto in enumerate(self.scene.prototypes):
            inst = self._buffer(_instance_data(proto.transforms))
            for j, mesh in enumerate(proto.meshes):
                if not mesh.triangle_count:
                    continue
                self._draws.append(
                    _Draw(
                        key=(i, j),
                        leaf=mesh.leaf,
                        positions=self._buffer(mesh.corners),
                        normals=self._buffer(face_normals(mesh.corners)),
                        instances=inst,
                        instance_count=len(proto.transforms),
                        indirect={name: self._buffer(values) for name, values in mesh.indirect.items()},
                        triangle_count=mesh.triangle_count,
                        smax=self._buffer(mesh.smax) if mesh.smax is not None and proto.tau is not None else None,
                        tau=float(proto.tau or 0.0),
                        omega=proto.sample_directions(np.asarray(self.scene.up, dtype=np.float64)) if mesh.smax is not None else None,
                        transforms=np.asarray(proto.transforms, dtype=np.float64),
                        **self._lb_upload(mesh, len(proto.transforms)),
                    )
                )
        self._ground_inst = self._buffer(_instance_data(np.eye(4)[None]))
        self._ground_vbo = None
        self._ground_nbo = None
        self._ground_key: tuple | None = None

    def _lb_upload(self, mesh: DrawMesh, instances: int) -> dict:
        """The LB relighting bases as a texture (texel vertex * 18 + k) and the per-instance weight buffer."""
        if mesh.lb_bases is None:
            return {}
        per_vertex = np.ascontiguousarray(np.transpose(mesh.lb_bases, (1, 0, 2)), dtype=np.float32).reshape(-1, 3)
        width = min(self.max_texture, 4096)
        rows = -(-len(per_vertex) // width)
        if rows > self.max_texture:
            raise UsageError(f"the LB relighting bases of {mesh.triangle_count} triangles need a {width}x{rows} texture; "
                             f"this GL allows {self.max_texture} per side. Preview with --lod, or use the baked sun (bake --bases sun).")
        data = np.zeros((rows * width, 3), np.float32)
        data[: len(per_vertex)] = per_vertex
        tex = self.ctx.texture((width, rows), 3, data.tobytes(), dtype="f4")
        tex.filter = (self.ctx.NEAREST, self.ctx.NEAREST)
        self._lb_textures.append(tex)
        return {"lb_tex": tex, "lb_width": width, "lb_inst": self._buffer(np.zeros((max(instances, 1), 6), np.float32))}

    def _lb_weights(self, draw: _Draw, sun: np.ndarray) -> None:
        """steele2010 sec. 3.1 per instance: the hull face hit by the light's travel direction in the instance's
        frame and its barycentric weights (lattice.barycentric_weights), written to the instance buffer."""
        from foliage_tools.geometry.sun import to_prototype_space
        from foliage_tools.lighting.lb.lattice import barycentric_weights

        # _upload gives every draw its transforms, and lb_inst with lb_tex (render calls this only with lb_tex)
        assert draw.transforms is not None and draw.lb_inst is not None

        rows = np.zeros((len(draw.transforms), 6), np.float32)
        for i, m in enumerate(draw.transforms):
            try:
                local = to_prototype_space(sun, m)
            except ValueError:  # a degenerate (zero-scale) instance draws nothing anyway
                continue
            idx, w = barycentric_weights(-np.asarray(local, dtype=np.float64))
            rows[i, :3] = np.asarray(idx, dtype=np.float32) - 1.0  # lattice directions 1..18 -> bases 0..17
            rows[i, 3:] = w
        draw.lb_inst.write(rows.tobytes())

    def _vao(self, program_key: tuple[str, bool | str], draw: _Draw, indirect_name: str | None):
        key = (program_key, draw.key, indirect_name)
        if key not in self._vaos:
            prog = self._program(*program_key)
            content = [(draw.positions, "3f", "in_position"), (draw.instances, *INSTANCE_LAYOUT)]
            if program_key[0] != "shadow":
                content.append((draw.normals, "3f", "in_normal"))
            if indirect_name == "smax":
                assert draw.smax is not None  # render asks for "smax" only for draws with s_max
                content.append((draw.smax, "4f 4f", "in_smax0", "in_smax1"))
            elif indirect_name == "lb-relight":
                assert draw.lb_inst is not None  # render asks for "lb-relight" only for draws with the LB bases
                content.append((draw.lb_inst, "3f 3f/i", "in_lb_index", "in_lb_weight"))
            elif indirect_name is not None:
                content.append((draw.indirect[indirect_name], "3f", "in_indirect"))
            self._vaos[key] = self.ctx.vertex_array(prog, content, skip_errors=True)
        return self._vaos[key]

    def _ground_vao(self, ground: Ground):
        key = (tuple(np.asarray(ground.point, dtype=np.float64)), ground.radius, ground.detail, ground.rings, ground.segments)
        if self._ground_key != key:
            old_vao = self._vaos.pop(("ground",), None)
            if old_vao is not None:
                old_vao.release()
            for buf in (self._ground_vbo, self._ground_nbo):
                if buf is not None:
                    self._buffers.remove(buf)
                    buf.release()
            corners = ground.corners(np.asarray(self.scene.up, dtype=np.float64)).astype(np.float32)
            self._ground_vbo = self._buffer(corners)
            self._ground_nbo = self._buffer(face_normals(corners))
            self._ground_key = key
        vao_key = ("ground",)
        if vao_key not in self._vaos:
            prog = self._program("ground")
            self._vaos[vao_key] = self.ctx.vertex_array(
                prog,
                [(self._ground_vbo, "3f", "in_position"), (self._ground_nbo, "3f", "in_normal"), (self._ground_inst, *INSTANCE_LAYOUT)],
                skip_errors=True,
            )
        return self._vaos[vao_key]

    def _render_targets(self, width: int, height: int):
        """Float radiance + tree mask + depth at the supersampled size (reused while the size stays)."""
        if self._target_size != (width, height):
            if self._targets is not None:
                for obj in self._targets:
                    obj.release()
            color = self.ctx.renderbuffer((width, height), 4, dtype="f4")
            mask = self.ctx.renderbuffer((width, height), 1, dtype="f4")
            depth = self.ctx.depth_renderbuffer((width, height))
            self._fbo = self.ctx.framebuffer([color, mask], depth)
            self._targets = [color, mask, depth, self._fbo]
            self._target_size = (width, height)
        return self._fbo

    # -- shadow and sky-visibility passes --------------------------------------------------
    def _fit_light(self, direction: np.ndarray, size: int) -> tuple[np.ndarray, float, float]:
        """Orthographic view-projection looking along −``direction`` that holds the scene bounds.

        Returns (view-projection, world size of a texel, depth range in world units).
        """
        lo, hi = self.bounds
        centre = (lo + hi) / 2
        radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
        up = np.asarray(self.scene.up, dtype=np.float64)
        up_hint = up if abs(direction @ up) < 0.99 else np.array([1.0, 0.0, 0.0]) if abs(direction[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        view = look_at(centre + direction * 2 * radius, centre, up_hint)
        rel = np.c_[bounds_corners(self.bounds), np.ones(8)] @ view.T
        (x0, y0, z0), (x1, y1, z1) = rel[:, :3].min(axis=0), rel[:, :3].max(axis=0)
        # square texels, padded by two texels so the PCF kernel stays inside the map
        side = max(x1 - x0, y1 - y0, 1e-6)
        pad = 2.0 * side / size
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        half = side / 2 + pad
        depth_pad = 0.01 * (z1 - z0) + pad
        proj = orthographic(cx - half, cx + half, cy - half, cy + half, -z1 - depth_pad, -z0 + depth_pad)
        return proj @ view, 2 * half / size, (z1 - z0) + 2 * depth_pad

    def _draw_depth(self, view_projection: np.ndarray) -> None:
        """All tree geometry, both faces, depth only, into the bound framebuffer and viewport."""
        self.ctx.disable(self.ctx.CULL_FACE)
        self.ctx.enable(self.ctx.DEPTH_TEST)
        self.ctx.depth_func = "<="
        prog = self._program("shadow")
        prog["u_view_projection"].write(_mat(view_projection))
        for draw in self._draws:
            self._vao(("shadow", False), draw, None).render(instances=draw.instance_count)

    def _shadow_pass(self, sun: np.ndarray) -> None:
        key = tuple(np.round(sun, 12))
        if self._shadow_key == key:
            return
        self._light_vp, self._texel_world, self._depth_range = self._fit_light(sun, self.shadow_size)
        self._shadow_fbo.use()
        self.ctx.viewport = (0, 0, self.shadow_size, self.shadow_size)
        self._shadow_fbo.clear(depth=1.0)
        self._draw_depth(self._light_vp)
        self._shadow_key = key

    def _sky_pass(self) -> None:
        """One depth map per sky direction, tiled in one texture; drawn once (the sky does not move)."""
        if self._sky_done:
            return
        self._sky_fbo.use()
        self.ctx.viewport = (0, 0, self._sky_tex.width, self._sky_tex.height)
        self._sky_fbo.clear(depth=1.0)
        texel, depth = 0.0, 1.0
        for k, d in enumerate(self._sky_dirs):
            vp, texel_k, depth_k = self._fit_light(d, SKY_TILE)
            self._sky_vps[k] = vp
            texel, depth = max(texel, texel_k), max(depth, depth_k)
            col, row = k % self._sky_tiles, k // self._sky_tiles
            self.ctx.viewport = (col * SKY_TILE, row * SKY_TILE, SKY_TILE, SKY_TILE)
            self._draw_depth(vp)
        self._sky_texel_world = texel
        self._sky_depth_bias = 2.0 * texel / depth
        self._sky_done = True
        if self.sky_samples:
            self._sky_cache_pass()

    def _sky_uniforms(self) -> dict[str, object]:
        return {
            "u_sky_map": 1,
            "u_sky_count": len(self._sky_dirs),
            "u_sky_tiles": self._sky_tiles,
            "u_sky_texel_world": self._sky_texel_world,
            "u_sky_texel": 1.0 / SKY_TILE,
            "u_sky_depth_bias": self._sky_depth_bias,
            "u_up": tuple(np.asarray(self.scene.up, dtype=np.float64)),
        }

    def _sky_uniform_arrays(self) -> dict[str, bytes]:
        return {
            "u_sky_view_projection": b"".join(_mat(m) for m in self._sky_vps),
            "u_sky_dir": np.ascontiguousarray(_padded(self._sky_dirs, MAX_SKY_SAMPLES), dtype=np.float32).tobytes(),
        }

    def _sky_cache_pass(self) -> None:
        """Sky visibility of every vertex of every instance, by transform feedback, into one RG texture per draw."""
        prog = self._program("skycache")
        for name, value in self._sky_uniform_arrays().items():
            if name in prog:
                prog[name].write(value)
        for name, scalar in self._sky_uniforms().items():
            if name in prog:
                prog[name].value = scalar
        self._sky_tex.use(location=1)
        for draw in self._draws:
            vertices = 3 * draw.triangle_count
            count = vertices * draw.instance_count
            width = min(count, SKY_CACHE_WIDTH)
            height = -(-count // width)
            if height > self.max_texture:
                raise UsageError(
                    f"{count:,} vertex instances need a {width}x{height} sky-visibility texture, more than this GL allows "
                    f"({self.max_texture}); use --sky-samples 0."
                )
            out = self.ctx.buffer(reserve=width * height * 8)
            vao = self.ctx.vertex_array(
                prog,
                [(draw.positions, "3f", "in_position"), (draw.normals, "3f", "in_normal"), (draw.instances, *INSTANCE_LAYOUT)],
                skip_errors=True,
            )
            vao.transform(out, mode=self.ctx.POINTS, vertices=vertices, instances=draw.instance_count)
            tex = self.ctx.texture((width, height), 2, dtype="f4")
            tex.filter = (self.ctx.NEAREST, self.ctx.NEAREST)
            tex.write(out)
            vao.release()
            out.release()
            draw.sky_cache, draw.sky_cache_width = tex, width

    # -- Boulanger's model (the smax method) ---------------------------------------------
    def _smax_uniforms(self, prog, draw: _Draw, optics: SurfaceOptics) -> None:
        """Per-tree constants of boulanger.glsl: τ, the ω_j in the prototype's frame, ρ_r and ρ_t (eq. (5.19))."""
        leaf = optics.leaf
        rho_r = np.asarray(leaf.reflectance_front, dtype=np.float64) + np.asarray(leaf.reflectance_back, dtype=np.float64)
        rho_t = np.asarray(leaf.transmittance_front, dtype=np.float64) + np.asarray(leaf.transmittance_back, dtype=np.float64)
        prog["u_omega"].write(np.ascontiguousarray(draw.omega, dtype=np.float32).tobytes())
        prog["u_tau"].value = draw.tau
        prog["u_sm_rho_r"].value = tuple(rho_r)
        prog["u_sm_rho_t"].value = tuple(rho_t)

    def smax_irradiance(self, lighting: Lighting, optics: SurfaceOptics | None = None) -> list[dict[str, Any]]:
        """Boulanger's per-leaf irradiance as the vertex shader computes it, read back by transform feedback.

        One dict per leaf draw that has s_max: ``key`` (prototype, mesh index) and, per
        vertex of every instance (instance-major, (N·3T,) or (N·3T, 3) float32), the unit-sun
        ``direct_front``/``direct_back`` (eq. (5.8)), ``scattered_front``/``scattered_back``
        (eqs. (5.11), (5.24)) and the sky and ground ``sky_front``/``sky_back`` (eq. (5.6)
        with eq. (5.29) for ``lighting.sky_radiance`` and the optics' ground reflectance).
        The main pass adds ``scattered_*`` times the sun's irradiance to the leaves.
        """
        from foliage_tools.lighting.envelope.boulanger import sky_radiance_per_direction

        optics = optics or SurfaceOptics()
        prog = self._program("smaxfeedback")
        sun = np.asarray(lighting.sun_direction, dtype=np.float64)
        prog["u_sun_dir"].value = tuple(sun / np.linalg.norm(sun))
        # a complete framebuffer must be bound even though transform feedback rasterises nothing
        # (the headless context's default framebuffer is not)
        self._shadow_fbo.use()
        out = []
        for draw in self._draws:
            if draw.smax is None:
                continue
            assert draw.omega is not None  # _upload sets omega for every mesh with s_max
            self._smax_uniforms(prog, draw, optics)
            local_up = -draw.omega[0] - draw.omega[1] - draw.omega[2] - draw.omega[3]  # ω_4..ω_7 lie above the horizon (eq. (5.28))
            sky = sky_radiance_per_direction(lighting.sky_radiance, optics.ground_reflectance, draw.omega, local_up)
            prog["u_smax_sky"].write(np.ascontiguousarray(sky, dtype=np.float32).tobytes())
            vertices = 3 * draw.triangle_count
            count = vertices * draw.instance_count
            floats = 2 + 4 * 3
            buf = self.ctx.buffer(reserve=count * floats * 4)
            vao = self.ctx.vertex_array(
                prog,
                [(draw.normals, "3f", "in_normal"), (draw.smax, "4f 4f", "in_smax0", "in_smax1"), (draw.instances, *INSTANCE_LAYOUT)],
                skip_errors=True,
            )
            vao.transform(buf, mode=self.ctx.POINTS, vertices=vertices, instances=draw.instance_count)
            raw = np.frombuffer(buf.read(), np.float32).reshape(count, floats)
            vao.release()
            buf.release()
            out.append(
                {
                    "key": draw.key,
                    "direct_front": raw[:, 0].copy(),
                    "direct_back": raw[:, 1].copy(),
                    "scattered_front": raw[:, 2:5].copy(),
                    "scattered_back": raw[:, 5:8].copy(),
                    "sky_front": raw[:, 8:11].copy(),
                    "sky_back": raw[:, 11:14].copy(),
                }
            )
        err = self.ctx.error
        if err != "GL_NO_ERROR":
            raise RuntimeError(f"OpenGL error while evaluating the smax model: {err}")
        return out

    # -- main pass ------------------------------------------------------------------
    def render(
        self,
        camera: Camera,
        lighting: Lighting,
        optics: SurfaceOptics | None = None,
        *,
        method: str | None = None,
        ground: Ground | None = None,
    ) -> Frame:
        """Draw one frame. ``method`` adds that method's indirect term to the leaves (None: direct only)."""
        optics = optics or SurfaceOptics()
        if method is not None and method not in self.scene.methods:
            raise ValueError(f"no indirect term {method!r} in the scene (have: {sorted(self.scene.methods)})")
        t0 = time.perf_counter()
        up = np.asarray(self.scene.up, dtype=np.float64)
        sun = np.asarray(lighting.sun_direction, dtype=np.float64)
        sun = sun / np.linalg.norm(sun)
        sun_irr = np.asarray(lighting.sun_irradiance, dtype=np.float64)
        sky = np.asarray(lighting.sky_radiance, dtype=np.float64)
        ground_radiance = np.zeros(3)
        if ground is not None:
            if sun @ up <= 0.0:
                sun_irr = np.zeros(3)  # the ground hides a sun below the horizon
            # ground bounce seen by the tree: Lambertian ground lit by the unshadowed sun and sky
            ground_radiance = np.asarray(optics.ground_reflectance) / math.pi * (sun_irr * max(float(sun @ up), 0.0) + math.pi * sky)
        self._shadow_pass(sun)
        self._sky_pass()

        k = self.supersample
        width, height = camera.width * k, camera.height * k
        if max(width, height) > self.max_size:
            raise UsageError(
                f"{camera.width}x{camera.height} pixels with {self.samples} samples each needs a {width}x{height} framebuffer; "
                f"this GL allows {self.max_size} per side. Use fewer --samples or a smaller --size."
            )
        fbo = self._render_targets(width, height)
        fbo.use()
        self.ctx.viewport = (0, 0, width, height)
        fbo.clear(red=0.0, green=0.0, blue=0.0, alpha=0.0, depth=1.0)  # clears the tree mask too
        self.ctx.disable(self.ctx.CULL_FACE)
        self.ctx.enable(self.ctx.DEPTH_TEST)
        self.ctx.depth_func = "<="
        self._shadow_tex.use(location=0)
        self._sky_tex.use(location=1)
        common = {
            "u_view_projection": _mat(camera.view_projection()),
            "u_light_view_projection": _mat(self._light_vp),
            **self._sky_uniform_arrays(),
        }
        scalars = {
            "u_sun_dir": tuple(sun),
            "u_sun_irradiance": tuple(sun_irr),
            "u_sky_radiance": tuple(sky),
            "u_ground_radiance": tuple(ground_radiance),
            "u_up": tuple(up),
            "u_camera_pos": tuple(camera.position),
            "u_view_dir": tuple(camera.forward),
            "u_orthographic": camera.orthographic,
            "u_shadow_map": 0,
            "u_shadow_texel_world": self._texel_world,
            "u_shadow_texel": 1.0 / self.shadow_size,
            # two texels' worth of depth slope, in [0, 1] depth units
            "u_shadow_depth_bias": 2.0 * self._texel_world / max(self._depth_range, 1e-12),
            **self._sky_uniforms(),
            "u_sky_cache": 2,
        }
        leaf = optics.leaf
        material: dict[str, dict[str, object]] = {
            "leaf": {
                "u_rho_rf": leaf.reflectance_front,
                "u_rho_rb": leaf.reflectance_back,
                "u_rho_tf": leaf.transmittance_front,
                "u_rho_tb": leaf.transmittance_back,
                "u_specular": leaf.specular,
                "u_roughness": leaf.roughness,
            },
            "wood": {"u_albedo": optics.wood_reflectance},
            "ground": {"u_albedo": optics.ground_reflectance},
        }

        def setup(prog, kind: str) -> None:
            for name, value in common.items():
                if name in prog:
                    prog[name].write(value)
            for name, scalar in {**scalars, **material[kind]}.items():
                if name in prog:
                    prog[name].value = scalar

        for draw in self._draws:
            kind = "leaf" if draw.leaf else "wood"
            name: str | None
            key: tuple[str, bool | str]
            if method == "smax" and draw.smax is not None:
                name, key = "smax", (kind, "smax")
            elif method == "lb" and draw.lb_tex is not None:
                name, key = "lb-relight", (kind, "lb-relight")
            else:
                name = method if (method is not None and method in draw.indirect) else None
                key = (kind, name is not None)
            prog = self._program(*key)
            setup(prog, kind)
            if name == "smax":
                self._smax_uniforms(prog, draw, optics)
            if name == "lb-relight":
                self._lb_weights(draw, sun)
                assert draw.lb_tex is not None  # "lb-relight" is chosen above only when it is
                draw.lb_tex.use(location=3)
                prog["u_lb_bases"].value = 3
                prog["u_lb_width"].value = draw.lb_width
            if draw.sky_cache is not None:
                draw.sky_cache.use(location=2)
                prog["u_sky_cache_width"].value = draw.sky_cache_width
                prog["u_vertex_count"].value = 3 * draw.triangle_count
            self._vao(key, draw, name).render(instances=draw.instance_count)
        if ground is not None:
            vao = self._ground_vao(ground)
            setup(vao.program, "ground")
            vao.render(instances=1)

        rgba = np.frombuffer(fbo.read(components=4, dtype="f4", attachment=0), np.float32).reshape(height, width, 4)[::-1]
        tree = np.frombuffer(fbo.read(components=1, dtype="f4", attachment=1), np.float32).reshape(height, width)[::-1]
        rgba, tree = _box_filter(rgba, k), _box_filter(tree, k)
        err = self.ctx.error
        if err != "GL_NO_ERROR":
            raise RuntimeError(f"OpenGL error while rendering: {err}")
        return Frame(
            radiance=np.ascontiguousarray(rgba[:, :, :3]),
            alpha=np.ascontiguousarray(rgba[:, :, 3]),
            tree=np.ascontiguousarray(tree),
            sky=cast(RGB, tuple(float(c) for c in sky)),  # Lighting checks sky_radiance has 3 values
            seconds=time.perf_counter() - t0,
        )

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        for prog in self._programs.values():
            prog.release()
        for buf in self._buffers:
            buf.release()
        for tex in self._lb_textures:
            tex.release()
        for obj in self._targets or ():
            obj.release()
        self._shadow_fbo.release()
        self._shadow_tex.release()
        self._sky_fbo.release()
        self._sky_tex.release()
        for draw in self._draws:
            if draw.sky_cache is not None:
                draw.sky_cache.release()
        self.ctx.release()
        self._vaos, self._programs, self._buffers, self._targets = {}, {}, [], None

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
