"""The package's layers (issue #20), read from the source: only ``scene/`` touches USD, OpenVDB and OIIO; the
numerical core never imports the pipeline or the CLI; no module-level import cycle.

Layers, bottom up: ``errors``/``params`` and the numerical core (``geometry``, ``lighting``), then ``scene``
(files), ``preview`` (drawing) and ``bench`` (methods), then ``pipeline`` (stages), then ``cli``.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "foliage_tools"
#: Third-party file-format and USD modules: only the scene layer may import them.
FORMATS = ("pxr", "pyopenvdb", "openvdb", "OpenImageIO")
FORMAT_LAYERS = ("foliage_tools.scene",)
#: The numerical core: pure arrays in, arrays out.
CORE = ("foliage_tools.geometry", "foliage_tools.lighting")
ABOVE_CORE = ("foliage_tools.pipeline", "foliage_tools.cli", "foliage_tools.scene", "foliage_tools.bench",
              "foliage_tools.preview")


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("")
        name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        yield name, path, ast.parse(path.read_text(), filename=str(path))
    for path in sorted((ROOT / "cli").rglob("*.py")):
        rel = path.relative_to(ROOT / "cli").with_suffix("")
        parts = ("foliage_tools", "cli") + (rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        yield ".".join(parts), path, ast.parse(path.read_text(), filename=str(path))


def _imports(module: str, tree: ast.AST, *, top_level_only: bool):
    """(imported module, line) of every import; with ``top_level_only`` those run at import time (not in a
    function, nor under ``if TYPE_CHECKING``)."""
    def visit(node, deferred):
        for child in ast.iter_child_nodes(node):
            inner = deferred or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)) or (
                isinstance(child, ast.If) and "TYPE_CHECKING" in ast.dump(child.test))
            if isinstance(child, ast.Import) and not (top_level_only and deferred):
                for alias in child.names:
                    yield alias.name, child.lineno
            elif isinstance(child, ast.ImportFrom) and not (top_level_only and deferred):
                if child.level:  # relative: resolve against the package
                    base = module.split(".")[: -child.level] if not module.endswith("__init__") else module.split(".")
                    target = ".".join(base + ([child.module] if child.module else []))
                else:
                    target = child.module or ""
                yield target, child.lineno
                for alias in child.names:  # `from foliage_tools.lighting import lb` imports a module
                    yield f"{target}.{alias.name}", child.lineno
            yield from visit(child, inner)

    yield from visit(tree, False)


def _within(name: str, prefixes) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def test_only_the_scene_layer_touches_usd_openvdb_and_oiio():
    offenders = [f"{path.relative_to(ROOT)}:{line} imports {target}"
                 for module, path, tree in _modules() if not _within(module, FORMAT_LAYERS)
                 for target, line in _imports(module, tree, top_level_only=False)
                 if target.split(".")[0] in FORMATS]
    assert not offenders, "move these into foliage_tools/scene/:\n" + "\n".join(offenders)


def test_the_numerical_core_imports_no_layer_above_it():
    offenders = [f"{path.relative_to(ROOT)}:{line} imports {target}"
                 for module, path, tree in _modules() if _within(module, CORE)
                 for target, line in _imports(module, tree, top_level_only=False) if _within(target, ABOVE_CORE)]
    assert not offenders, "\n".join(offenders)


def test_no_import_cycle_at_import_time():
    modules = {module: tree for module, _, tree in _modules()}
    graph = {m: sorted({t for t, _ in _imports(m, tree, top_level_only=True) if t in modules and t != m})
             for m, tree in modules.items()}
    # a package's __init__ is imported before its modules: an edge into a package is an edge into its __init__
    cycles, state = [], {}

    def walk(m, stack):
        state[m] = "open"
        for t in graph[m]:
            if state.get(t) == "open":
                cycles.append(" -> ".join(stack[stack.index(t):] + [t]))
            elif t not in state:
                walk(t, stack + [t])
        state[m] = "done"

    for m in graph:
        if m not in state:
            walk(m, [m])
    assert not cycles, "import cycles at import time:\n" + "\n".join(cycles)


def test_the_scan_sees_imports():
    """The checks above pass on an empty scan too: they must see the imports the package has."""
    found = {t for m, _, tree in _modules() if m == "foliage_tools.scene.read"
             for t, _ in _imports(m, tree, top_level_only=False)}
    assert "pxr" in found
    graph_edges = sum(1 for m, _, tree in _modules() for _ in _imports(m, tree, top_level_only=True))
    assert graph_edges > 200


def test_openvdb_is_imported_at_use_only():
    # pyopenvdb comes from a Debian package, not pip: a module that imports it at import time makes every module
    # importing that one (the pipeline, the tests of pure numerics) need it. scene/vdb.py imports it in its functions.
    top = [(name, line) for name, _, tree in _modules() for mod, line in _imports(name, tree, top_level_only=True)
           if _within(mod, ("pyopenvdb", "openvdb"))]
    assert not top, top
