"""A symbolic link at an output's name: the output is written by its own name, never through the link.

The commit renames each file over its final name, which replaces a link there
by the file itself; the layer must name its grid files by those names too
(a layer that named the link's target would point outside the output).
"""

from __future__ import annotations

from pathlib import Path

from pxr import Sdf

from tests.helpers.cli import foliage

MINIMAL = Path(__file__).resolve().parents[1] / "corpus" / "clean" / "minimal_tree.usda"
FAST = ("--resolution", "8", "--gather", "16", "--direct-samples", "16")


def _setup(tmp_path: Path) -> tuple[Path, Path, Path]:
    out = tmp_path / "out"
    out.mkdir()
    tree = tmp_path / "tree.usda"
    tree.write_bytes(MINIMAL.read_bytes())
    victim = tmp_path / "victim.txt"
    victim.write_text("victim\n")
    return tree, out, victim


def _grid_paths(layer: Path) -> set[str]:
    """The asset paths of the OpenVDB fields the layer itself authors (as written, unresolved)."""
    found = set()
    lay = Sdf.Layer.FindOrOpen(str(layer))

    def visit(path: Sdf.Path) -> None:
        if path.IsPropertyPath() and path.name == "filePath":
            value = lay.GetAttributeAtPath(path).default
            if value is not None:
                found.add(value.path)

    lay.Traverse(Sdf.Path.absoluteRootPath, visit)
    return found


def test_a_symlink_at_a_grid_name_is_replaced_and_the_layer_names_the_grid_itself(tmp_path):
    tree, out, victim = _setup(tmp_path)
    (out / "x.vdb").symlink_to("../victim.txt")
    r = foliage("density", tree, "-o", out / "x.usda", "--resolution", "8")
    assert r.returncode == 0, r.stderr
    assert victim.read_text() == "victim\n"
    assert (out / "x.vdb").is_file() and not (out / "x.vdb").is_symlink()
    assert _grid_paths(out / "x.usda") == {"./x.vdb"}
    assert "victim" not in (out / "x.usda").read_text()
    assert foliage("validate", out / "x.usda").returncode == 0


def test_a_symlink_at_the_layer_name_is_replaced_by_the_layer(tmp_path):
    tree, out, victim = _setup(tmp_path)
    (out / "x.usda").symlink_to("../victim.txt")
    r = foliage("density", tree, "-o", out / "x.usda", "--resolution", "8")
    assert r.returncode == 0, r.stderr
    assert victim.read_text() == "victim\n"
    assert (out / "x.usda").is_file() and not (out / "x.usda").is_symlink()
    assert _grid_paths(out / "x.usda") == {"./x.vdb"}


def test_symlinks_at_a_bakes_output_names_are_replaced_by_its_files(tmp_path):
    tree, out, victim = _setup(tmp_path)
    for name in ("tree.lb.vdb", "tree.lb.usda", "tree.density.vdb", "tree.png"):
        (out / name).symlink_to("../victim.txt")
    r = foliage("bake", tree, "-o", out, *FAST)
    assert r.returncode == 0, r.stderr
    assert victim.read_text() == "victim\n"
    assert not [p.name for p in out.iterdir() if p.is_symlink()]
    assert _grid_paths(out / "tree.lb.usda") == {"./tree.lb.vdb"}
    assert _grid_paths(out / "tree.density.usda") == {"./tree.density.vdb"}
    assert foliage("validate", out / "tree.lb.usda").returncode == 0
