"""The asset corpus (issue #20): what the real CLI says on each file of ``tests/corpus/clean`` and ``tests/corpus/bad``.

Each baseline ``tests/corpus/baseline/<stem>.<command>.txt`` holds ``exit N`` on its first line, then stdout, then
(when there is any) ``--- stderr`` and stderr. The CLI runs with cwd = the corpus folder, a relative path and
COLUMNS=100, so no absolute path gets in. To update after an intended change: run with FOLIAGE_UPDATE_GOLDEN=1
and review the diff. After changing ``tests/corpus/generate.py``: run it, then update the baselines.
"""

from __future__ import annotations

import filecmp
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers.cli import foliage

CORPUS = Path(__file__).resolve().parents[1] / "corpus"
BASELINE = CORPUS / "baseline"

CLEAN = sorted(p.name for p in (CORPUS / "clean").glob("*.usda"))
BAD = sorted(p.name for p in (CORPUS / "bad").glob("*.usda"))
#: bad files `foliage inspect` opens (the other three it refuses with validate's message, before reading anything)
INSPECT_BAD = tuple(n for n in BAD if n not in ("empty_file.usda", "not_usd_text.usda", "syntax_error.usda"))
#: the files whose validate findings are warnings only: --strict turns them into exit 1
STRICT_BAD = ("degenerate_leaf_triangles.usda", "instancer_nested.usda", "instancer_prototype_is_instancer.usda",
              "leaf_optics_attributes.usda")
#: known findings (tests/corpus/README.md), pinned so that a fix shows up as a baseline diff: remove the file from
#: here when its baseline changes for the better. A crash (exit 3) of validate and inspect:
KNOWN_CRASHES: tuple[str, ...] = ()
#: ... and files validate passes (exit 0) although the bakes refuse them or leave part of them out:
VALIDATE_MISSES: tuple[str, ...] = ()

CASES = (
    [("clean", f, "validate") for f in CLEAN]
    + [("clean", f, "inspect") for f in CLEAN]
    + [("clean", f, "plan") for f in CLEAN]
    + [("bad", f, "validate") for f in BAD]
    + [("bad", f, "validate --strict") for f in STRICT_BAD]
    + [("bad", f, "inspect") for f in INSPECT_BAD]
)

#: plan's one machine-dependent line: a warning when the LB bake's memory exceeds the memory free now
FREE_MEMORY = re.compile(r"^warning: the LB bake would hold .* of memory free now: .*\n", re.M)
#: what varies between machines and USD builds in text the CLI passes on from USD: where a crash log went (time,
#: process id), the source file and line of USD's own diagnostics, its versioned C++ namespace, a stage's address,
#: and the absolute paths USD resolves asset paths to
NORMALISE = (
    (re.compile(r"A crash log is at \S+\.log"), "A crash log is at <CRASH_LOG>"),
    (re.compile(r"at line \d+ (of|in file) \S*/pxr/"), r"at line <N> \1 <USD>/pxr/"),
    (re.compile(r"pxrInternal_v[\d_]+__pxrReserved__"), "pxrInternal_<VERSION>"),
    (re.compile(r"<0x[0-9a-f]+>"), "<0x...>"),
    (re.compile(re.escape(str(CORPUS))), "<CORPUS>"),
)


def baseline_path(name: str, command: str) -> Path:
    return BASELINE / f"{Path(name).stem}.{command.replace(' --', '-')}.txt"


def cli_text(folder: str, name: str, command: str) -> str:
    r = foliage(*command.split(), name, cwd=CORPUS / folder)
    text = f"exit {r.returncode}\n{r.stdout}"
    if r.stderr:
        text += f"--- stderr\n{r.stderr}"
    text = FREE_MEMORY.sub("", text)
    for pattern, replacement in NORMALISE:
        text = pattern.sub(replacement, text)
    return text


@pytest.fixture(autouse=True)
def _columns(monkeypatch):
    monkeypatch.setenv("COLUMNS", "100")


@pytest.mark.parametrize(("folder", "name", "command"), CASES, ids=[f"{f}/{n}:{c}" for f, n, c in CASES])
def test_cli_text_matches_baseline(folder, name, command):
    text = cli_text(folder, name, command)
    golden = baseline_path(name, command)
    if os.environ.get("FOLIAGE_UPDATE_GOLDEN"):
        golden.parent.mkdir(parents=True, exist_ok=True)
        golden.write_text(text)
    assert golden.exists(), f"no baseline {golden.name}: run with FOLIAGE_UPDATE_GOLDEN=1"
    assert text == golden.read_text()
    code = int(text.split("\n", 1)[0].split()[1])
    if name in KNOWN_CRASHES:
        assert code == 3, f"{name} no longer crashes: take it off KNOWN_CRASHES"
        return
    assert code != 3, f"{folder}/{name}: `foliage {command}` crashed:\n{text}"
    if folder == "clean":
        assert code == 0, text
    elif command == "validate":
        expected = (0,) if name in STRICT_BAD + VALIDATE_MISSES else (1, 2)
        assert code in expected, f"{name}: validate exit {code}, expected {expected} (see VALIDATE_MISSES)"
    elif command == "validate --strict":
        assert code == 1, text


def test_every_bad_file_is_named_in_its_validate_text():
    """A bad file's validate text names the file (by the relative path it was given), crashes aside."""
    for name in set(BAD) - set(KNOWN_CRASHES):
        text = baseline_path(name, "validate").read_text()
        assert name in text, f"{name}: validate's text does not name the file"


#: foliage rules whose findings open with the file, as the rules built on scene.bakeable do (transforms, ...)
NAMES_THE_FILE = ("instancers", "nested-instancing", "empty-meshes", "leaf-meshes-found", "transforms", "stage-units",
                  "leaf-area")


def test_findings_of_the_foliage_rules_name_the_file_first():
    """The independent fact: the file name each validate run was given; a finding of these rules starts with it as
    @name@ (nested-instancing and empty-meshes named only the prim)."""
    seen = set()
    for name in BAD:
        for line in baseline_path(name, "validate").read_text().splitlines():
            rule = re.match(r"^(?:error|warning) \[([\w:-]+)\] ", line)
            if rule and rule[1] in NAMES_THE_FILE:
                seen.add(rule[1])
                assert line[rule.end():].startswith(f"@{name}@"), line
    assert {"instancers", "nested-instancing", "empty-meshes"} <= seen, seen


def test_no_baseline_is_left_over():
    expected = {baseline_path(n, c).name for _, n, c in CASES}
    assert {p.name for p in BASELINE.glob("*.txt")} == expected


def test_generator_reproduces_the_committed_corpus(tmp_path):
    """tests/corpus/generate.py writes the committed files byte for byte (so they cannot drift from it)."""
    r = subprocess.run([sys.executable, str(CORPUS / "generate.py"), str(tmp_path)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""  # writing the corpus composes nothing: USD has nothing to complain about
    for sub in ("clean", "bad"):
        made = sorted(str(p.relative_to(tmp_path / sub)) for p in (tmp_path / sub).rglob("*") if p.is_file())
        committed = sorted(str(p.relative_to(CORPUS / sub)) for p in (CORPUS / sub).rglob("*") if p.is_file())
        assert made == committed, f"{sub}/: the generator's files differ from the committed ones"
        _, mismatch, errors = filecmp.cmpfiles(tmp_path / sub, CORPUS / sub, made, shallow=False)
        assert mismatch == [] and errors == [], f"{sub}/: regenerate with tests/corpus/generate.py: {mismatch + errors}"


def test_readme_lists_every_file_with_validate_exit_code():
    rows = re.findall(r"^\| `(clean|bad)/([\w.]+)` \|.*\| exit (\d)\b", (CORPUS / "README.md").read_text(), re.M)
    listed = {(folder, name): int(code) for folder, name, code in rows}
    assert set(listed) == {("clean", n) for n in CLEAN} | {("bad", n) for n in BAD}
    for (_folder, name), code in listed.items():
        first = baseline_path(name, "validate").read_text().split("\n", 1)[0]
        assert first == f"exit {code}", f"README says exit {code} for {name}, the baseline {first}"
