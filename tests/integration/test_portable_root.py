"""``bake --portable`` copies only files under the input's folder (or ``--portable-root``), never any file an asset
path names: an asset path is the input's to write, and a bake must not read files it was not asked to into its
output (``@/etc/passwd@`` as a texture)."""

from __future__ import annotations

import os
from pathlib import Path

from pxr import Sdf, Usd

from tests.helpers.cli import foliage

CORPUS = Path(__file__).resolve().parents[1] / "corpus" / "clean" / "minimal_tree.usda"
FAST = ("--resolution", "8", "--gather", "16", "--direct-samples", "16", "--direct", "rays")


def _asset(tmp_path: Path) -> tuple[Path, Path]:
    """A tree in ``tmp_path/asset`` naming four files: one inside its folder, an absolute path, a ``../`` path and a
    symlink inside the folder, the last three to ``tmp_path/secret.txt`` outside it."""
    folder = tmp_path / "asset"
    (folder / "tex").mkdir(parents=True)
    (folder / "tex" / "leaf.png").write_bytes(b"leaf texture")
    secret = tmp_path / "secret.txt"
    secret.write_text("not the asset's to ship\n")
    os.symlink(secret, folder / "tex" / "link.png")
    tree = folder / "tree.usda"
    tree.write_text(CORPUS.read_text())
    stage = Usd.Stage.Open(str(tree))
    leaves = stage.GetPrimAtPath("/Tree/Leaves")
    for name, asset in (("inside", "./tex/leaf.png"), ("absolute", str(secret)), ("climbing", "../secret.txt"),
                        ("linked", "./tex/link.png")):
        leaves.CreateAttribute(f"test:{name}", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(asset))
    stage.GetRootLayer().Save()
    return tree, secret


def _copies(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in out.iterdir() if ".input." in p.name and p.suffix != ".usda"}


def test_portable_copies_only_files_under_the_inputs_folder(tmp_path):
    tree, secret = _asset(tmp_path)
    out = tmp_path / "out"
    run = foliage("bake", tree, "-o", out, "--portable", *FAST)
    assert run.returncode == 0, run.stderr
    copies = _copies(out)
    # the texture inside the folder travels; nothing with the secret's content does, by any of the three routes
    assert copies == {"tree.input.leaf.png": b"leaf texture"}, copies
    assert not any(secret.read_bytes() == data for data in copies.values())
    # each path left out is named in a warning that says why and what to do
    for shown in (str(secret), "link.png"):
        assert shown in run.stderr, run.stderr
    assert "--portable-root" in run.stderr and "not copied" in run.stderr
    # the flattened input keeps those paths as authored by the composed stage (not copies), so nothing points into out/
    stage = Usd.Stage.Open(str(out / "tree.input.usda"))
    leaves = stage.GetPrimAtPath("/Tree/Leaves")
    assert leaves.GetAttribute("test:inside").Get().path == "./tree.input.leaf.png"
    for name in ("absolute", "climbing", "linked"):
        kept = leaves.GetAttribute(f"test:{name}").Get().path
        assert not kept.startswith("./tree.input."), (name, kept)


def test_portable_root_widens_the_folder_copies_are_taken_from(tmp_path):
    tree, secret = _asset(tmp_path)
    out = tmp_path / "out"
    run = foliage("bake", tree, "-o", out, "--portable-root", tmp_path, *FAST)  # implies --portable
    assert run.returncode == 0, run.stderr
    copies = _copies(out)
    assert copies["tree.input.leaf.png"] == b"leaf texture"
    # the secret, reached by three paths, is one file: copied once, under its own resolved name
    assert copies["tree.input.secret.txt"] == secret.read_bytes()
    assert "not copied" not in run.stderr, run.stderr


def test_portable_root_must_be_a_folder(tmp_path):
    tree, secret = _asset(tmp_path)
    run = foliage("bake", tree, "-o", tmp_path / "out", "--portable-root", secret, *FAST)
    assert run.returncode == 2 and "portable-root" in run.stderr, run.stderr
    assert not (tmp_path / "out").exists()
