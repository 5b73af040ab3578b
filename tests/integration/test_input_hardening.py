"""Inputs that try to make a command read, copy or report files it was not asked to, and values read as the wrong thing."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from tests.helpers.cli import foliage

CORPUS = Path(__file__).resolve().parents[1] / "corpus"
TREE = CORPUS / "clean" / "minimal_tree.usda"
FAST = ("--resolution", "8", "--gather", "16", "--direct-samples", "16")


def _tree_with(tmp_path: Path, layer_data: str = "", name: str = "tree.usda", text: str | None = None) -> Path:
    """The minimal tree with ``layer_data`` added to its customLayerData."""
    text = TREE.read_text() if text is None else text
    if layer_data:
        text = text.replace('string "foliage:generator" = "tests/corpus/generate.py"',
                            'string "foliage:generator" = "tests/corpus/generate.py"\n        ' + layer_data, 1)
    out = tmp_path / name
    out.write_text(text)
    return out


# -- a forged bake record (customLayerData foliage.files) --------------------------------------------------------------

@pytest.fixture
def secret(tmp_path: Path) -> Path:
    victim = tmp_path / "outside" / "secret.txt"
    victim.parent.mkdir()
    victim.write_text("not for foliage to read\n")
    return victim


def _forged(tmp_path: Path, entry: str) -> Path:
    folder = tmp_path / "in"
    folder.mkdir()
    return _tree_with(folder, f'dictionary foliage = {{ dictionary files = {{ string "{entry}" = "sha256:00" }} }}')


@pytest.mark.parametrize("entry", ["../outside/secret.txt", "SECRET_ABS", "./../outside/secret.txt"])
def test_forged_record_is_refused_without_reading_the_file(tmp_path: Path, secret: Path, entry: str) -> None:
    entry = str(secret) if entry == "SECRET_ABS" else entry
    tree = _forged(tmp_path, entry)
    leaked = hashlib.sha256(secret.read_bytes()).hexdigest()[:12]
    v = foliage("validate", tree, "--json")
    assert v.returncode == 1, v.stderr
    messages = [f["message"] for f in json.loads(v.stdout)["stats"]["findings"] if f["rule"] == "bake-files-match"]
    assert len(messages) == 1 and "not one foliage wrote" in messages[0] and f"@{tree}@" in messages[0], messages
    assert leaked not in v.stdout + v.stderr
    b = foliage("bake", tree, "-o", tmp_path / "out", *FAST, "-q")
    assert b.returncode == 2, b.stderr
    assert messages[0] in b.stderr and leaked not in b.stdout + b.stderr


# -- a forged batch.json -----------------------------------------------------------------------------------------------

def test_batch_cache_hit_needs_the_assets_own_outputs_under_outroot(tmp_path: Path) -> None:
    outputs = ["../victim.txt", "/etc/hostname", "tree/../../victim.txt"]
    tree = _tree_with(tmp_path)
    root = tmp_path / "root"
    first = foliage("batch", tree, "-o", root, *FAST, "--json")
    assert first.returncode == 0, first.stderr
    (tmp_path / "victim.txt").write_text("victim\n")
    record = json.loads((root / "batch.json").read_text())
    record["assets"]["tree"]["outputs"] = outputs
    (root / "batch.json").write_text(json.dumps(record))
    (root / "tree").rename(tmp_path / "moved")
    dry = foliage("batch", tree, "-o", root, *FAST, "--dry-run", "--json")
    assert dry.returncode == 0, dry.stderr
    entry = json.loads(dry.stdout)["stats"]["assets"]["tree"]
    assert entry["action"] == "bake" and "not one foliage wrote" in entry["reason"], entry
    again = foliage("batch", tree, "-o", root, *FAST, "--json")
    assert again.returncode == 0, again.stderr
    report = json.loads(again.stdout)
    assert report["stats"]["assets"]["tree"]["status"] == "baked"
    for out in report["outputs"]:
        assert Path(out).resolve().is_relative_to(root.resolve()), report["outputs"]
    assert (root / "tree" / "tree.lb.usda").is_file()


# -- bake --portable: layers from outside the folder, copy names ---------------------------------------------------------

def _portable(tree: Path, tmp_path: Path) -> tuple[list[Path], list[str]]:
    from foliage_tools.scene.portable import write_portable_input

    staging = tmp_path / "staging"
    staging.mkdir()
    warnings: list[str] = []
    return write_portable_input(tree, staging, warnings), warnings


def test_portable_names_layers_composed_from_outside_the_folder(tmp_path: Path) -> None:
    shared = tmp_path / "shared"
    shared.mkdir()
    (shared / "extra.usda").write_text('#usda 1.0\ndef Xform "Extra"\n{\n}\n')
    (shared / "ref.usda").write_text('#usda 1.0\n(\n    defaultPrim = "Ref"\n)\ndef Xform "Ref"\n{\n}\n')
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "inside.usda").write_text('#usda 1.0\ndef Xform "Inside"\n{\n}\n')
    text = TREE.read_text().replace('    upAxis = "Z"\n', '    subLayers = [@../shared/extra.usda@, @./inside.usda@]\n    upAxis = "Z"\n', 1)
    text += f'\ndef Xform "Referenced" (\n    prepend references = @{shared / "ref.usda"}@\n)\n{{\n}}\n'
    tree = _tree_with(tmp_path / "in", text=text)
    written, warnings = _portable(tree, tmp_path)
    composed = [w for w in warnings if "composed into @tree.input.usda@" in w]
    assert sorted(composed) == sorted(w for w in composed if str(shared) in w) and len(composed) == 2, warnings
    assert any("extra.usda@" in w for w in composed) and any("ref.usda@" in w for w in composed)
    assert not any("inside.usda" in w for w in warnings) and not any(f"@{tree}@" in w for w in warnings)


def test_portable_copy_never_takes_the_flattened_layers_name(tmp_path: Path) -> None:
    from pxr import Sdf, Usd

    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "usda").write_bytes(b"texture bytes\n")
    text = TREE.read_text().replace('    def Mesh "Trunk"\n    {\n',
                                    '    def Mesh "Trunk"\n    {\n        asset foliage:texture = @./usda@\n', 1)
    tree = _tree_with(tmp_path / "in", text=text)
    written, warnings = _portable(tree, tmp_path)
    layer_file = tmp_path / "staging" / "tree.input.usda"
    assert written[-1] == layer_file and len(set(written)) == len(written) == 2, written
    stage = Usd.Stage.Open(str(layer_file))
    asset = stage.GetPrimAtPath("/Tree/Trunk").GetAttribute("foliage:texture").Get()
    assert isinstance(asset, Sdf.AssetPath) and asset.path != "./tree.input.usda", asset
    assert (tmp_path / "staging" / asset.path).read_bytes() == b"texture bytes\n"
    assert stage.GetPrimAtPath("/Tree/Leaves").IsValid()


# -- primvars:foliage:isLeaf that is not a bool -------------------------------------------------------------------------

@pytest.mark.parametrize("authored", ['string primvars:foliage:isLeaf = "no"', "bool[] primvars:foliage:isLeaf = []",
                                      "int primvars:foliage:isLeaf = 0"])
def test_is_leaf_that_is_not_a_bool_is_refused_with_one_message(tmp_path: Path, authored: str) -> None:
    text = TREE.read_text().replace('    def Mesh "Trunk"\n    {\n', f'    def Mesh "Trunk"\n    {{\n        {authored}\n', 1)
    tree = _tree_with(tmp_path, text=text)
    v = foliage("validate", tree, "--json")
    assert v.returncode == 1, v.stderr
    found = [f for f in json.loads(v.stdout)["stats"]["findings"] if f["rule"] == "attribute-types"]
    assert len(found) == 1 and found[0]["prim"] == "/Tree/Trunk", found
    message = found[0]["message"]
    assert "<" + "/Tree/Trunk>" in message and "`bool primvars:foliage:isLeaf = true`" in message
    b = foliage("bake", tree, "-o", tmp_path / "out", *FAST, "-q")
    assert b.returncode == 2 and message in b.stderr, b.stderr
    assert not (tmp_path / "out" / "tree.lb.usda").exists()
    i = foliage("inspect", tree)
    assert i.returncode != 3, i.stderr


def test_why_bake_with_the_assets_name_refuses_another_assets_folder(tmp_path: Path) -> None:
    from foliage_tools.pipeline.batch_cache import Key, why_bake

    for folder in ("tree", "oak"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / f"{folder}.lb.usda").write_text("#usda 1.0\n")
    key = Key(digest="k", files={"tree.usda": "h"}, options={}, tool="t")
    entry = {"status": "baked", "tool": "t", "options": {}, "files": {"tree.usda": "h"}, "key": "k"}
    assert why_bake(key, {**entry, "outputs": ["tree/tree.lb.usda"]}, tmp_path, name="tree") is None
    assert "not one foliage wrote" in str(why_bake(key, {**entry, "outputs": ["oak/oak.lb.usda"]}, tmp_path, name="tree"))
    assert "missing" in str(why_bake(key, {**entry, "outputs": ["tree/tree.density.usda"]}, tmp_path, name="tree"))
