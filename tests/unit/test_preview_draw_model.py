"""The preview's draw model (foliage_tools.preview.draw_model) needs no GL (issue #20: one module per concept).

DrawScene and the rest are plain arrays that the pipeline and the LOD builder make before any GL
context exists; renderer.py imports moderngl only where it creates the context. A fresh
interpreter in which ``import moderngl`` fails must still import both and build a scene.
"""

from __future__ import annotations

import os
import subprocess
import sys

from tests.conftest import REPO

CODE = """
import sys
sys.modules["moderngl"] = None  # every import of moderngl now raises ImportError
import numpy as np
from foliage_tools.preview import draw_model, renderer
corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
mesh = draw_model.DrawMesh(corners=corners, leaf=True)
scene = draw_model.DrawScene((draw_model.DrawPrototype((mesh,), np.eye(4)[None]),), np.array([0.0, 0.0, 1.0]))
assert scene.triangle_count == 1 and scene.bounds().shape == (2, 3)
assert draw_model.face_normals(corners)[0].tolist() == [0.0, 0.0, 1.0]
# the names the renderer always had are the draw model's
for name in ("DrawMesh", "DrawPrototype", "DrawScene", "Lighting", "Ground", "Frame", "face_normals", "sky_directions"):
    assert getattr(renderer, name) is getattr(draw_model, name), name
assert "moderngl" not in {m for m, v in sys.modules.items() if v is not None}
"""


def test_draw_model_and_renderer_import_without_moderngl():
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    run = subprocess.run([sys.executable, "-c", CODE], cwd=REPO, env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
