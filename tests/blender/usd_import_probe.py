"""Run by Blender's Python (the ``bpy`` module, in its own venv): import a USD file with Blender's default
options and print, as one JSON line prefixed ``PROBE``, what arrived (objects, volume grids, attributes,
custom properties). Used by tests/integration/test_blender_roundtrip.py; it imports nothing of foliage_tools.

    python usd_import_probe.py FILE.usda
"""

import json
import sys

import bpy
import mathutils


def _plain(value):
    if hasattr(value, "to_list"):
        return value.to_list()
    if hasattr(value, "__len__") and not isinstance(value, str):
        return [_plain(v) for v in value]
    return value


def main(path: str) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.usd_import(filepath=path)  # Blender's defaults: no guide/proxy purposes, custom attributes kept
    bpy.context.view_layer.update()  # parented objects' matrix_world is evaluated, not set by the import
    objects = []
    for ob in bpy.data.objects:
        d = {"name": ob.name, "type": ob.type, "props": {k: _plain(v) for k, v in ob.items()},
             "parent": ob.parent.name if ob.parent else None,
             "matrix_world": [list(row) for row in ob.matrix_world]}
        if ob.type == "VOLUME":
            vol = ob.data
            vol.grids.load()
            d["filepath"] = bpy.path.abspath(vol.filepath)
            d["grids"] = [{"name": g.name, "data_type": g.data_type, "channels": g.channels,
                           "matrix": [list(row) for row in g.matrix_object]} for g in vol.grids]
            d["data_props"] = {k: _plain(v) for k, v in vol.items()}
            d["materials"] = [m.name for m in vol.materials if m]
            # the object's bounding box from its loaded grids (evaluated), in world space
            evaluated = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
            d["world_bound_box"] = [list(ob.matrix_world @ mathutils.Vector(c)) for c in evaluated.bound_box]
        elif ob.type == "MESH":
            mesh = ob.data
            d["faces"] = len(mesh.polygons)
            attrs = {}
            for a in mesh.attributes:
                if not a.name.startswith("foliage:"):
                    continue
                if a.data_type in ("FLOAT", "INT"):
                    values = [v.value for v in a.data]
                elif a.data_type in ("FLOAT_COLOR", "FLOAT_VECTOR"):
                    values = [list(v.color if a.data_type == "FLOAT_COLOR" else v.vector)[:3] for v in a.data]
                else:
                    values = None
                attrs[a.name] = {"domain": a.domain, "data_type": a.data_type, "values": values}
            d["attributes"] = attrs
        objects.append(d)
    scene = bpy.context.scene
    print("PROBE" + json.dumps({"objects": objects, "unit_scale": scene.unit_settings.scale_length,
                                "blender": bpy.app.version_string}))


if __name__ == "__main__":
    main(sys.argv[-1])
