"""``foliage bake``: the main job chains the stages, each layer over the previous one."""

import json
from pathlib import Path

import pytest

from foliage_tools.lighting.optics import parse_leaf_optics
from foliage_tools.pipeline.bake import BakeParams, run_bake
from tests.helpers.cli import foliage

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "tree_small.usda"


def test_bake_chains_stages_and_the_last_layer_holds_everything(tmp_path):
    from pxr import Usd, UsdGeom, UsdVol

    report = run_bake(EXAMPLE, tmp_path / "out", BakeParams(optics=parse_leaf_optics(None), resolution=12, with_reference=True,
                                                          reference_paths=50000))
    final = Path(report.stats["result"])
    assert final.name == "tree_small.lb.usda"
    stage = Usd.Stage.Open(str(final))
    leaves = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Tree/Leaves"))
    for name in ("foliage:leafId", "foliage:smax", "foliage:lbIndirect", "foliage:lb:scattered", "foliage:smax:scattered", "foliage:sppIrradiance", "foliage:sppg:scattered"):
        assert leaves.GetPrimvar(name).HasAuthoredValue(), name
    fields = set(UsdVol.Volume(stage.GetPrimAtPath("/Tree/FoliageLighting")).GetFieldPaths())
    assert {"density", "woodFraction", "lbSun", "sppGFactor", "sppDepth", "sppThickness"} <= fields
    assert (tmp_path / "out" / "tree_small.png").stat().st_size > 1000
    assert (tmp_path / "out" / "bench.json").stat().st_size > 100 and (tmp_path / "out" / "bench.png").exists()
    assert foliage("validate", final).returncode == 0
    # the reference as a layer over the bake: a preview can compare the bake with it
    ref = tmp_path / "out" / "tree_small.ref.usda"
    assert str(ref) in report.outputs and foliage("validate", ref).returncode == 0
    ref_stage = Usd.Stage.Open(str(ref))
    ref_leaves = UsdGeom.PrimvarsAPI(ref_stage.GetPrimAtPath("/Tree/Leaves"))
    assert ref_leaves.GetPrimvar("foliage:ref:scattered").HasAuthoredValue()
    assert ref_leaves.GetPrimvar("foliage:lb:scattered").HasAuthoredValue()  # over the bake
    r = foliage("preview", ref, "-o", tmp_path / "cmp.png", "--compare", "lb,reference", "--error-image", "--size", "64x64")
    assert r.returncode == 0, r.stderr


@pytest.mark.slow  # > 15 s; the default suite keeps a faster test of the same path
def test_bake_of_a_forest_of_native_instances_writes_everything_and_the_per_instance_light(tmp_path):
    from pxr import Usd, UsdGeom

    forest = EXAMPLE.with_name("forest_small.usda")
    report = run_bake(forest, tmp_path / "out", BakeParams(optics=parse_leaf_optics(None), resolution=12))
    final = Path(report.stats["result"])
    # its prototypes are native instances: no per-leaf primvars, so the preview shows the direct light only, and says so
    assert (tmp_path / "out" / "forest_small.png").stat().st_size > 1000
    assert any("preview: every prototype is a native instance" in w for w in report.warnings)
    stage = Usd.Stage.Open(str(final))
    grove = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Grove"))
    for m in ("smax", "spp", "lb"):
        d = grove.GetPrimvar(f"foliage:{m}:instanceDirect").Get()
        assert len(d) == 12 and min(v[0] for v in d) > 0, m
        assert stage.GetPrimAtPath("/World/Trees/Tree_00").GetAttribute(f"foliage:{m}:instanceScattered").Get()[1] > 0, m
    assert foliage("validate", final).returncode == 0


def test_bake_into_a_file_path_is_refused(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    r = foliage("bake", EXAMPLE, "-o", f)
    assert r.returncode == 2


class _InterruptAt:
    """A progress sink that raises KeyboardInterrupt (Ctrl-C) at the first step whose message contains ``word``."""

    def __init__(self, word: str):
        self.word = word
        self.seen = []

    def step(self, message: str, total=None) -> None:
        self.seen.append(message)
        if self.word in message:
            raise KeyboardInterrupt

    def advance(self, n: int = 1) -> None:
        pass


def test_an_interrupted_bake_leaves_no_output_and_keeps_an_existing_outdir_as_it_was(tmp_path):
    import pytest

    optics = parse_leaf_optics(None)
    # interrupted in the LB stage: density, smax and spp had finished
    progress = _InterruptAt("lattice")
    with pytest.raises(KeyboardInterrupt):
        run_bake(EXAMPLE, tmp_path / "new" / "out", BakeParams(optics=optics, resolution=8), progress=progress)
    assert any("lattice" in m for m in progress.seen)
    assert list(tmp_path.iterdir()) == []  # neither OUTDIR, nor the directory made for it, nor a temporary
    existing = tmp_path / "old"
    existing.mkdir()
    (existing / "notes.txt").write_text("keep me")
    with pytest.raises(KeyboardInterrupt):
        run_bake(EXAMPLE, existing, BakeParams(optics=optics, resolution=8), progress=_InterruptAt("lattice"))
    assert [f.name for f in tmp_path.iterdir()] == ["old"] and [f.name for f in existing.iterdir()] == ["notes.txt"]


def test_bake_with_bad_input_or_an_unwritable_place_exits_2_and_creates_nothing(tmp_path):
    from tests.conftest import cards_mesh, write_mesh_stage

    wood = write_mesh_stage(tmp_path / "wood.usda", {"Trunk": {**cards_mesh([(0, 0, 0)]), "isLeaf": False}})
    r = foliage("bake", wood, "-o", tmp_path / "a" / "b", "--resolution", "8")
    assert r.returncode == 2 and "no leaves" in r.stderr
    assert sorted(f.name for f in tmp_path.iterdir()) == ["wood.usda"]
    # /proc refuses new files and directories even to root
    r = foliage("bake", EXAMPLE, "-o", "/proc/foliage-bake", "--resolution", "8")
    assert r.returncode == 2 and "/proc" in r.stderr, r.stderr


def test_bake_stages_inside_outdir_and_writes_nothing_beside_it(tmp_path, monkeypatch):
    # Staging beside OUTDIR made a bake onto a mount point fail at the end ("Invalid cross-device link") and
    # needed a writable parent. Every rename now happens inside OUTDIR: the parent never sees a file.
    from foliage_tools.scene import atomic

    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    seen = []

    def watch(index, staged, final):
        seen.append((staged.parent.parent, final.parent, sorted(p.name for p in tmp_path.iterdir())))

    monkeypatch.setattr(atomic, "before_rename", watch)
    report = run_bake(EXAMPLE, out, BakeParams(optics=parse_leaf_optics(None), resolution=8))
    assert Path(report.stats["result"]) == out / "tree_small.lb.usda"
    assert len(seen) == 8  # the bake's 8 files, in one commit
    assert all(stage_dir == out and final_dir == out and beside == ["out"] for stage_dir, final_dir, beside in seen)
    assert sorted(p.name for p in out.iterdir()) == sorted(["notes.txt", *(
        f"tree_small.{n}" for n in ("density.usda", "density.vdb", "smax.usda", "spp.usda", "spp.vdb", "lb.usda", "lb.vdb", "png"))])
    assert foliage("validate", out / "tree_small.lb.usda").returncode == 0


def test_layer_format_usdc_writes_binary_layers_that_chain_and_validate(tmp_path, monkeypatch):
    from pxr import Sdf, UsdGeom

    from foliage_tools.pipeline import bake as bake_module
    from foliage_tools.scene.read import open_stage

    report = run_bake(EXAMPLE, tmp_path / "out", BakeParams(optics=parse_leaf_optics(None), resolution=8, layer_format="usdc"))
    final = Path(report.stats["result"])
    assert final.name == "tree_small.lb.usdc" and final.read_bytes()[:8] == b"PXR-USDC"  # the crate file's magic
    # each stage's peak memory so far: a process peak, so it never falls from one stage to the next
    peaks = [st["peak_rss_bytes"] for st in report.stats["stages"].values()]
    assert peaks[0] > 50e6 and peaks == sorted(peaks)
    # each stage's own stats ride along, so a pipeline step can check the bake's quality from its report
    lb_stage = report.stats["stages"]["lb"]["stats"]
    assert lb_stage["prototypes"][0]["converged"] and lb_stage["prototypes"][0]["residual"] < 1e-5
    assert report.stats["stages"]["spp"]["stats"]["gather"]["rays_per_leaf"] == 1024
    layer = Sdf.Layer.FindOrOpen(str(final))
    assert list(layer.subLayerPaths)[0].endswith("tree_small.spp.usdc")
    stage = open_stage(final)
    leaves = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Tree/Leaves"))
    assert leaves.GetPrimvar("foliage:lbIndirect").HasAuthoredValue() and leaves.GetPrimvar("foliage:smax:scattered").HasAuthoredValue()
    assert foliage("validate", final).returncode == 0
    # auto: text for the 1500-leaf example, binary from LAYER_USDC_LEAVES prototype leaves on
    assert bake_module.layer_extension(EXAMPLE, BakeParams(optics=parse_leaf_optics(None))) == "usda"
    monkeypatch.setattr(bake_module, "LAYER_USDC_LEAVES", 1500)
    assert bake_module.layer_extension(EXAMPLE, BakeParams(optics=parse_leaf_optics(None))) == "usdc"
    with pytest.raises(Exception, match="--layer-format must be one of"):
        BakeParams(optics=parse_leaf_optics(None), layer_format="json")


def test_progress_reaches_a_log_without_a_terminal(tmp_path, monkeypatch):
    # a pipeline step or CI (stderr is a pipe): every step as a plain timed line, and a long step's share done
    from foliage_tools.cli import console

    r = foliage("smax", EXAMPLE, "-o", tmp_path / "a.usda")
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("[")]
    assert r.returncode == 0 and any("direct sunlight" in ln for ln in lines) and lines[-1].endswith("a.usda")
    assert not [ln for ln in foliage("smax", EXAMPLE, "-o", tmp_path / "b.usda", "-q").stderr.splitlines() if ln.startswith("[")]
    monkeypatch.setattr(console, "PLAIN_EVERY_S", 0.0)
    seen = []
    monkeypatch.setattr(console.RichProgress, "_print", lambda self, text: seen.append(text))
    p = console.RichProgress(enabled=True)
    p.plain, p.enabled = True, False
    p.step("tracing", total=4)
    p.advance(2)
    assert seen == ["tracing", "tracing: 50 % (2/4)"]


def test_bake_grid_precision_half_stores_the_lb_grids_half_and_keeps_the_density_float(tmp_path):
    """``bake --grid-precision half`` reaches the lb stage: its lbSun is half (scene.vdb.Grid.half), the density
    carried into the same .vdb stays the float32 its stage wrote (later stages read it), and the batch key differs."""
    from foliage_tools.pipeline.batch_cache import asset_key
    from foliage_tools.scene.vdb import read_grid

    r = foliage("bake", EXAMPLE, "-o", tmp_path / "out", "--resolution", "8", "--direct-samples", "16", "--gather", "0",
                "--grid-precision", "half")
    assert r.returncode == 0, r.stderr
    lb_vdb = tmp_path / "out" / "tree_small.lb.vdb"
    assert read_grid(lb_vdb, "lbSun").half and not read_grid(lb_vdb, "density").half
    assert foliage("validate", tmp_path / "out" / "tree_small.lb.usda").returncode == 0
    keys = {p: asset_key(EXAMPLE, BakeParams(optics=parse_leaf_optics(None), grid_precision=p)).digest for p in ("float", "half")}
    assert keys["float"] != keys["half"]
    with pytest.raises(Exception, match="--grid-precision must be one of"):
        BakeParams(optics=parse_leaf_optics(None), grid_precision="double")


def test_bake_says_which_config_keys_do_not_reach_its_stages(tmp_path):
    # a file shared by a pipeline: [lb] and lb's max-sweeps apply to `foliage lb`, not to bake's lb stage, which
    # takes bake's own options; bake ran without them silently (a new user's trial)
    cfg = tmp_path / "pipeline.toml"
    cfg.write_text("resolution = 8\nmax-sweeps = 3\n[lb]\ntolerance = 1e-4\n")
    r = foliage("bake", EXAMPLE, "-o", tmp_path / "out", "--gather", "0", "--config", cfg, "--json")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    notes = [w for w in report["warnings"] if "pipeline.toml" in w]
    assert len(notes) == 1 and "[lb] table" in notes[0] and "max-sweeps" in notes[0], report["warnings"]
    assert report["stats"]["stages"]["lb"]["stats"]["prototypes"][0]["resolution"][0] <= 10  # the top level's 8 did
    from tests.helpers.typed_json import assert_typed_stats

    assert_typed_stats(report)
    for name, stage in report["stats"]["stages"].items():  # each stage's stats as its own command prints them
        assert_typed_stats({"command": name, "stats": stage["stats"]})


def test_a_warning_about_the_input_names_the_input_once_not_each_stages_temporary_layer(tmp_path):
    """Each stage reads the layer the stage before wrote in the staging folder: a warning about the input's content
    (here a mesh with faces but no face vertex indices, which every stage skips) names the input file, once, with
    the stages that gave it, and no temporary layer (``.NAME.bake.tmp-PID-TOKEN/...``) is named."""
    src = tmp_path / "card.usda"
    src.write_text("""#usda 1.0
(
    defaultPrim = "Tree"
    metersPerUnit = 1
    upAxis = "Z"
)
def Xform "Tree" (kind = "component")
{
    def Mesh "Broken"
    {
        point3f[] points = [(0, 0, 1), (0.1, 0, 1), (0.1, 0.1, 1)]
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = []
    }
    def Mesh "leaf"
    {
        point3f[] points = [(0, 0, 1), (0.1, 0, 1), (0.1, 0.1, 1), (0, 0.1, 1)]
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
    }
}
""")
    r = foliage("bake", src, "-o", tmp_path / "out", "--resolution", "8", "--direct-samples", "8", "--json")
    assert r.returncode == 0, r.stderr
    warnings = json.loads(r.stdout)["warnings"]
    broken = [w for w in warnings if "</Tree/Broken>" in w]
    assert len(broken) == 1 and str(src) in broken[0], warnings
    assert not any(".tmp-" in w for w in warnings), warnings
