"""Hostile inputs and environments end in exit 2 (or the command's own code) with a message that names the file or
the option, never exit 3, a signal death, a traceback or a hang; with ``--json`` stdout is one JSON error object.

These run the real command (``python -m foliage_tools``) in a subprocess.
"""

from __future__ import annotations

import base64
import json
import os
import resource
import struct
import subprocess
import sys
import time
from pathlib import Path

import click
import jsonschema
import pytest

from tests.helpers.cli import REPO, REPORT_SCHEMA, foliage

TREE = REPO / "tests" / "corpus" / "clean" / "minimal_tree.usda"


def assert_json_error(r: subprocess.CompletedProcess, code: int = 2) -> dict:
    """stdout is one JSON error object of the report schema, with the exit code."""
    report = json.loads(r.stdout)
    jsonschema.validate(report, REPORT_SCHEMA)
    assert report["error"]["code"] == code == r.returncode, (r.returncode, r.stderr)
    return report


def assert_clean_exit(r: subprocess.CompletedProcess, code: int = 2) -> None:
    assert r.returncode == code, (r.returncode, r.stderr[-2000:])
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr[-2000:]


# -- mesh files whose counts or indices the file does not back: pymeshlab's readers crash or ask for gigabytes

def _gltf(path: Path, indices=(0, 1, 2), count: int = 3, position=(0, 0, 0, 1, 0, 0, 0, 1, 0)) -> Path:
    data = struct.pack("<9f", *position) + struct.pack("<3H", *indices) + b"\0\0"
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(data), "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 6}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": count, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
                      {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}],
        "meshes": [{"name": "leaf", "primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}], "scene": 0,
    }
    path.write_text(json.dumps(doc))
    return path


PLY = ("ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nelement face 1\n"
       "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")

BAD_MESHES = {
    # name: (file name, contents or writer, words the message has)
    "gltf-index-past-positions": ("t.gltf", lambda p: _gltf(p, indices=(0, 1, 7)), ("index 7", "3 positions")),
    "gltf-accessor-count": ("t.gltf", lambda p: _gltf(p, count=100_000_000), ("accessor 0", "100,000,000")),
    "gltf-nan-position": ("t.gltf", lambda p: _gltf(p, position=(0, 0, 0, 1, float("nan"), 0, 0, 1, 0)), ("NaN",)),
    "off-index-out-of-range": ("t.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 9\n", ("face 0", "vertex 9")),
    "off-negative-counts": ("t.off", "OFF\n-3 -1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", ("counts", "-3 -1 0")),
    "off-counts-past-the-data": ("t.off", "OFF\n30 10 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", ("30 vertices", "4 lines")),
    "ply-negative-vertex-count": ("t.ply", PLY.format(n=-5), ("element vertex -5", "header")),
    "ply-huge-vertex-count": ("t.ply", PLY.format(n=4_000_000_000), ("element vertex 4000000000", "header")),
    "obj-nan-vertex": ("t.obj", "v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n", ("vertex 2", "finite")),
}


@pytest.mark.parametrize("case", sorted(BAD_MESHES))
def test_a_damaged_mesh_file_is_exit_2_naming_the_file_and_the_element(tmp_path, case):
    name, contents, words = BAD_MESHES[case]
    model = tmp_path / name
    if callable(contents):
        contents(model)
    else:
        model.write_text(contents)
    r = foliage("import", model, "-o", tmp_path / "tree.usda", "--all-leaves", "--json")
    assert_clean_exit(r)
    report = assert_json_error(r)
    message = report["error"]["message"]
    assert str(model) in message and report["inputs"] == [str(model)], message
    assert all(w in message for w in words), message
    assert "more memory" not in message
    assert not (tmp_path / "tree.usda").exists()


def test_a_reader_crash_the_checks_do_not_foresee_is_an_input_error_naming_the_file(tmp_path):
    # the file's own read in a child process: pymeshlab dies by SIGSEGV on this accessor count (check_file refuses
    # it first in `foliage import`; a form it does not know ends the same way, as exit 2)
    from foliage_tools.errors import InputError
    from foliage_tools.scene.meshfile import _probe

    model = _gltf(tmp_path / "t.gltf", count=100_000_000)
    with pytest.raises(InputError, match=r"t\.gltf@: pymeshlab's reader crashed on this file \(SIG"):
        _probe(model)
    _probe(_gltf(tmp_path / "sound.gltf"))  # a sound file passes


def test_a_sound_gltf_still_imports(tmp_path):
    r = foliage("import", _gltf(tmp_path / "t.gltf"), "-o", tmp_path / "tree.usda", "--all-leaves")
    assert r.returncode == 0, r.stderr


# -- options: checked where they are given, naming the option

@pytest.mark.parametrize("args, option", [
    (("import", "{gltf}", "-o", "{out}", "--merge-distance", "nan"), "--merge-distance"),
    (("import", "{gltf}", "-o", "{out}", "--merge-distance", "inf"), "--merge-distance"),
    (("import", "{gltf}", "-o", "{out}", "--simplify", "nan"), "--simplify"),
    (("import", "{gltf}", "-o", "{out}", "--meters-per-unit", "inf"), "--meters-per-unit"),
    (("density", "{tree}", "-o", "{out}", "--voxel-size", "nan"), "--voxel-size"),
    (("reference", "{tree}", "-o", "{out}", "--seed", "18446744073709551617"), "--seed"),
    (("lb", "{tree}", "-o", "{out}", "--sun", "400,30"), "--sun"),
    (("lb", "{tree}", "-o", "{out}", "--sun", "45,-30"), "--sun"),
    (("batch", "{tree}", "-o", "{outdir}", "--scheduler", "garbage://x"), "--scheduler"),
    (("batch", "{tree}", "-o", "{outdir}", "--scheduler", "tcp://host-without-port"), "--scheduler"),
])
def test_a_bad_option_value_is_exit_2_at_the_option(tmp_path, args, option):
    names = {"gltf": _gltf(tmp_path / "t.gltf"), "tree": TREE, "out": tmp_path / "o.usda", "outdir": tmp_path / "out"}
    started = time.monotonic()
    r = foliage(*(a.format(**names) for a in args), "--json")
    assert_clean_exit(r)
    assert_json_error(r)
    assert f"Invalid value for '{option}'" in r.stderr or f"'{option}'" in r.stderr, r.stderr
    assert time.monotonic() - started < 30  # refused before any work (a bad scheduler address took 40 s)
    assert not [p for p in tmp_path.iterdir() if p.name != "t.gltf"]


def test_sun_messages_give_the_direction_a_wrapped_azimuth_stands_for(tmp_path):
    r = foliage("lb", TREE, "-o", tmp_path / "o.usda", "--sun", "400,30")
    assert r.returncode == 2 and "40,30" in r.stderr, r.stderr
    config = tmp_path / "c.toml"
    config.write_text('sun = "-90,45"\n')
    r = foliage("lb", TREE, "-o", tmp_path / "o.usda", "--config", config)
    assert r.returncode == 2 and "c.toml" in r.stderr and "270,45" in r.stderr, r.stderr


def test_every_float_option_of_every_command_refuses_nan_and_inf():
    from foliage_tools.cli.main import cli

    floats = [(name, p) for name, cmd in cli.commands.items() for p in cmd.params
              if isinstance(p.type, click.types.FloatParamType)]
    assert len(floats) > 10
    for name, p in floats:
        for bad in ("nan", "inf", "-inf"):
            with pytest.raises(click.BadParameter, match="finite"):
                p.type.convert(bad, p, None)
        assert p.type.convert("0.5", p, None) == 0.5 or p.name in ("wood_reflectance",), (name, p.name)


def test_an_output_name_with_no_room_for_the_writes_temporary_is_refused_before_any_work(tmp_path):
    out = tmp_path / ("a" * 250 + ".usda")  # 255 bytes: fits the filesystem, but not USD's temporary beside it
    r = foliage("density", TREE, "-o", out, "--resolution", "8", "--json")
    assert_clean_exit(r)
    assert_json_error(r)
    assert "shorter name" in r.stderr and "255 bytes" in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_config_nested_thousands_deep_is_exit_2_naming_the_file(tmp_path):
    config = tmp_path / "deep.toml"
    config.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    r = foliage("density", TREE, "-o", tmp_path / "o.usda", "--config", config)
    assert_clean_exit(r)
    assert "deep.toml" in r.stderr and "nests" in r.stderr


# -- stdout and stderr that cannot be written

def _run(args, **streams) -> subprocess.CompletedProcess:
    env = dict(os.environ, XDG_CACHE_HOME=str(Path("/tmp") / "foliage-test-cache"))
    return subprocess.run([sys.executable, "-m", "foliage_tools", *map(str, args)], env=env, timeout=300, **streams)


def test_a_closed_or_full_stdout_is_exit_2_saying_so():
    closed = _run(["validate", TREE, "--json"], stderr=subprocess.PIPE, text=True, preexec_fn=lambda: os.close(1))
    assert_clean_exit(closed)
    assert "stdout" in closed.stderr and "closed" in closed.stderr
    with open("/dev/full", "w") as full:
        r = _run(["validate", TREE, "--json"], stdout=full, stderr=subprocess.PIPE, text=True)
    assert_clean_exit(r)
    assert "stdout" in r.stderr and "No space left" in r.stderr
    with open("/dev/full", "w") as full:  # a table wider than 80 columns, and click's own help
        for args in (["inspect", TREE], ["--help"]):
            r = _run(args, stdout=full, stderr=subprocess.PIPE, text=True)
            assert_clean_exit(r)
            assert "stdout" in r.stderr, (args, r.stderr)


def test_a_full_or_closed_stderr_keeps_the_commands_own_exit_code(tmp_path):
    with open("/dev/full", "w") as full:
        r = _run(["validate", tmp_path / "nope.usda", "--json"], stdout=subprocess.PIPE, stderr=full, text=True)
        assert r.returncode == 2 and json.loads(r.stdout)["error"]["code"] == 2
        assert _run(["validate", TREE], stdout=subprocess.DEVNULL, stderr=full).returncode == 0
        assert _run(["density", TREE, "-o", tmp_path / "o.usda", "--resolution", "nine"], stdout=subprocess.DEVNULL,
                    stderr=full).returncode == 2
    r = _run(["validate", tmp_path / "nope.usda"], stdout=subprocess.PIPE, preexec_fn=lambda: os.close(2))
    assert r.returncode == 2


# -- names that are not plain text

def test_a_path_with_markup_in_it_prints_as_it_is(tmp_path):
    folder = tmp_path / "we[/]ird [b]x"  # the folder ``]ird [b]x`` in ``we[``
    folder.mkdir(parents=True)
    tree = folder / "t.usda"
    tree.write_bytes(TREE.read_bytes())
    r = foliage("inspect", tree)
    # the table's title names the file, folded at its space on a long temporary path: the markup-like parts stay
    # as they are (as markup, [/] would close nothing and [b] would vanish)
    assert r.returncode == 0 and "we[/]ird" in r.stdout and "[b]x/t.usda" in r.stdout, r.stdout + r.stderr
    r = foliage("density", tree, "-o", folder / "o.usda", "--resolution", "8")
    assert r.returncode == 0 and f"wrote {folder / 'o.usda'}" in r.stdout, r.stderr
    r = foliage("validate", folder / "missing.usda")
    assert_clean_exit(r)
    assert str(folder / "missing.usda") in r.stderr


@pytest.mark.parametrize("name, shown", [
    ("e\x1b[31mred.usda", "e\\x1b[31mred.usda"),
    ("cr\rover.usda", "cr\\rover.usda"),
    ("new\nline.usda", "new\\nline.usda"),
    ("byte\udcff.usda", "byte\\xff.usda"),  # the byte 0xff, as Python's surrogateescape reads it from argv
])
def test_control_characters_and_bytes_in_a_file_name_are_shown_escaped(tmp_path, name, shown):
    r = _run(["validate", tmp_path / name], capture_output=True)
    assert r.returncode == 2, r.stderr
    err = r.stderr.decode("utf-8")  # strict: every byte printed is UTF-8
    assert shown in err and "\x1b" not in err and "\r" not in err and "Traceback" not in err, err
    r = _run(["inspect", tmp_path / name, "--json"], capture_output=True)
    assert r.returncode == 2 and json.loads(r.stdout)["error"]["code"] == 2


def test_click_usage_errors_and_log_lines_show_control_characters_escaped(tmp_path):
    r = _run(["validate", "--x\x1b[31m"], capture_output=True, text=True)
    assert r.returncode == 2 and "--x\\x1b[31m" in r.stderr and "\x1b" not in r.stderr, r.stderr
    folder = tmp_path / "in\x1b[2J"
    folder.mkdir()
    tree = folder / "t.usda"
    tree.write_bytes(TREE.read_bytes())
    # the reader refuses a file name USD cannot take (test_input_rules_files.py), shown escaped, never acted on
    r = _run(["inspect", tree, "-v"], capture_output=True, text=True)
    assert r.returncode == 2 and "in\\x1b[2J" in r.stderr and "\x1b" not in r.stderr + r.stdout, r.stderr
    # a layer over it would name it as its sublayer, which USD cannot hold: refused before any work
    r = _run(["density", tree, "-o", tmp_path / "o.usda", "--resolution", "8", "--json"], capture_output=True, text=True)
    assert_clean_exit(r)
    assert_json_error(r)
    assert "in\\x1b[2J" in r.stderr and "control character" in r.stderr and "\x1b" not in r.stderr
    # an output name USD cannot write as an asset path: refused at the option, before any work
    r = _run(["density", TREE, "-o", tmp_path / "o\x1b[2J.usda", "--json"], capture_output=True, text=True)
    assert_clean_exit(r)
    assert_json_error(r)
    assert "o\\x1b[2J.usda" in r.stderr and "control character" in r.stderr and "\x1b" not in r.stderr


# -- a user's pattern cannot hang the import

def test_a_backtracking_leaf_pattern_on_a_long_part_name_does_not_hang(tmp_path):
    model = tmp_path / "t.obj"
    model.write_text(f"o {'a' * 30_000}b\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "cache"))
    started = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "foliage_tools", "import", str(model), "-o", str(tmp_path / "t.usda"),
                        "--leaves", "(a+)+$"], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr  # no part matches: all wood, with a warning
    assert time.monotonic() - started < 60
    assert "(a+)+$" in r.stderr


def test_a_pattern_the_linear_engine_cannot_read_is_exit_2_naming_it(tmp_path):
    model = _gltf(tmp_path / "t.gltf")
    r = foliage("import", model, "-o", tmp_path / "t.usda", "--leaves", "(?<=x)leaf", "--json")
    assert_clean_exit(r)
    assert_json_error(r)
    assert "--leaves '(?<=x)leaf'" in r.stderr and "look-arounds" in r.stderr


# -- memory caps (ulimit -v): below what the libraries need to load they crash in C; refused up front

@pytest.mark.parametrize("megabytes", [500, 1200, 1800])
def test_an_address_space_limit_too_small_to_load_the_libraries_is_exit_2_needs_more_memory(tmp_path, megabytes):
    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (megabytes << 20, megabytes << 20))

    for args in (["validate", TREE, "--json"], ["lb", TREE, "-o", tmp_path / "l.usda", "--resolution", "8", "--json"]):
        r = _run(args, capture_output=True, text=True, preexec_fn=cap)
        assert_clean_exit(r)
        report = assert_json_error(r)
        assert "needs more memory" in report["error"]["message"] and "ulimit -v" in r.stderr
    assert not (tmp_path / "l.usda").exists()
    assert _run(["validate", "--help"], capture_output=True, preexec_fn=cap).returncode == 0


def test_running_out_of_memory_mid_run_is_exit_2_naming_the_step(tmp_path):
    # above the floor, a lattice of 512 nodes a side (gigabytes) does not fit a 2.6 GB address space
    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (2600 << 20, 2600 << 20))

    r = _run(["lb", TREE, "-o", tmp_path / "l.usda", "--resolution", "512", "--gather", "16", "--direct-samples", "16",
              "--json"], capture_output=True, text=True, preexec_fn=cap)
    assert_clean_exit(r)
    message = assert_json_error(r)["error"]["message"]
    assert "needs more memory" in message and "at the step 'lattice-Boltzmann" in message, message
    assert not (tmp_path / "l.usda").exists()


def test_an_import_that_fails_for_lack_of_memory_is_told_from_a_missing_module():
    from foliage_tools.cli.common import environment_failure

    try:
        raise ImportError("libusd_ms.so: failed to map segment from shared object", name="pxr")
    except ImportError as exc:
        kind, message = environment_failure(exc)
    assert kind == "MemoryError" and "needs more memory" in message and "pxr" in message
    try:
        import foliage_tools_no_such_module  # noqa: F401
    except ImportError as exc:
        kind, message = environment_failure(exc)
    assert kind == "EnvironmentError" and "foliage_tools_no_such_module" in message and "reinstall" in message
    try:
        try:
            raise MemoryError
        except MemoryError as cause:
            raise ImportError("initialization of pyopenvdb raised unreported exception") from cause
    except ImportError as exc:
        assert environment_failure(exc)[0] == "MemoryError"
