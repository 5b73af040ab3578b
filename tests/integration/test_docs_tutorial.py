"""The tutorial works as written: every ```sh snippet of docs/tutorial.md runs, in order, in one shell, from a
fresh folder laid out as a checkout beside the project's shared/ folder, and leaves the files the tutorial says
it makes. So does the README's quick start.

The default run adds small-resolution options to the bake and the preview (so it takes seconds, not minutes);
the slow one runs every command exactly as the page prints it. `foliage` is the real command
(``python -m foliage_tools`` of the interpreter running the tests).
"""

from __future__ import annotations

import os
import re
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ASSETS

REPO = Path(__file__).resolve().parents[2]
TUTORIAL = REPO / "docs" / "tutorial.md"
README = REPO / "README.md"
#: options appended to a command of the tutorial for the fast run: the same steps on coarse grids, fewer rays, a
#: small image
FAST = {
    "foliage bake": "--resolution 16 --direct-samples 64 --gather 64",
    "foliage preview": "--size 96x96 --samples 1 --sky-samples 0 --shadow-size 256",
}


def snippets(text: str) -> list[str]:
    """The ```sh blocks of a Markdown page, in order."""
    return re.findall(r"^```sh\n(.*?)^```", text, flags=re.S | re.M)


def _script(fast: bool, page: Path = TUTORIAL) -> str:
    text = page.read_text(encoding="utf-8")
    if page == README:  # its quick start only (the install commands are the Makefile's)
        text = text[text.index("## Quick start"):]
        text = text[:text.index("\n## ", 1)]
    lines = []
    for block in snippets(text):
        for line in block.splitlines():
            command = line.split("#")[0].rstrip()
            if fast:
                for start, extra in FAST.items():
                    if command.startswith(start + " "):
                        command = f"{command} {extra}"
            if command:
                lines.append(command)
    return "set -euo pipefail\n" + "\n".join(lines) + "\n"


def _run_tutorial(tmp_path: Path, fast: bool, page: Path = TUTORIAL) -> tuple[Path, subprocess.CompletedProcess]:
    if not (ASSETS / "webots_oak" / "oak.obj").exists():
        pytest.skip(f"third-party assets not present at {ASSETS}")
    repo = tmp_path / "checkout"
    repo.mkdir()
    (tmp_path / "shared").symlink_to(ASSETS.parent, target_is_directory=True)
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    shim = bin_dir / "foliage"
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m foliage_tools "$@"\n')
    shim.chmod(shim.stat().st_mode | stat.S_IXUSR)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}",
               XDG_CACHE_HOME=str(tmp_path / "cache"), PYTHONPATH=os.pathsep.join(
                   p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p))
    r = subprocess.run(["bash", "-c", _script(fast, page)], cwd=repo, env=env, capture_output=True, text=True, timeout=1800)
    return repo, r


def test_the_tutorial_has_the_five_steps():
    script = _script(fast=False)
    steps = [script.index(f"foliage {cmd} ") for cmd in ("import", "inspect", "validate", "bake", "preview")]
    assert steps == sorted(steps), script


def _check(repo: Path, r: subprocess.CompletedProcess) -> None:
    assert r.returncode == 0, f"stdout:\n{r.stdout}\nstderr:\n{r.stderr}"
    work = repo / "my_tree"
    # what the tutorial says the steps leave
    for name in ("oak.usda", "oak_lb.png", "baked/oak.lb.usda", "baked/oak.lb.vdb", "baked/oak.density.usda",
                 "baked/oak.smax.usda", "baked/oak.spp.usda", "baked/oak.png"):
        assert (work / name).is_file(), name
    assert "1831" in r.stdout  # inspect's leaf count of the oak, as the tutorial says
    assert "passed" in r.stdout  # validate --strict

    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(work / "baked" / "oak.lb.usda"))
    assert UsdGeom.GetStageUpAxis(stage) == "Z"
    leaves = [p for p in stage.Traverse() if p.HasAttribute("primvars:foliage:lb:scattered")]
    assert leaves and all(p.HasAttribute("primvars:foliage:lb:direct") for p in leaves)


def test_every_command_of_the_tutorial_runs_on_small_grids(tmp_path):
    _check(*_run_tutorial(tmp_path, fast=True))


@pytest.mark.slow
def test_every_command_of_the_tutorial_runs_exactly_as_written(tmp_path):
    _check(*_run_tutorial(tmp_path, fast=False))


def test_the_readme_quick_start_runs_on_small_grids(tmp_path):
    repo, r = _run_tutorial(tmp_path, fast=True, page=README)
    assert r.returncode == 0, f"stdout:\n{r.stdout}\nstderr:\n{r.stderr}"
    out = repo / "out"
    for name in ("oak.usda", "oak.png", "oak_baked/oak.lb.usda", "oak_baked/oak.png"):
        assert (out / name).is_file(), name
