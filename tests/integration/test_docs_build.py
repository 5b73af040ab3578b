"""The user documentation: the MkDocs site builds with every warning an error (links between pages checked),
the README stays a two-minute read whose links resolve, the schema page documents every schema attribute,
and no user-facing text carries history (session or issue numbers, dates)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
HISTORY = re.compile(r"session [0-9]|issue #|2026-", re.IGNORECASE)
#: the places issue 42 names as user-facing text (foliage_tools/cli and foliage_tools/schemas are cli/ and schemas/)
USER_TEXT = ("README.md", "docs", "cli", "schemas")


def _build(root: Path, site: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
                          cwd=root, capture_output=True, text=True, timeout=300)


def test_the_docs_build_without_a_warning(tmp_path):
    r = _build(REPO, tmp_path / "site")
    assert r.returncode == 0, r.stderr
    cli_page = (tmp_path / "site" / "reference" / "cli" / "index.html").read_text(encoding="utf-8")
    # generated from the click commands: every command and a shared option are there
    from foliage_tools.cli.main import cli

    for name in cli.commands:
        assert f"foliage {name}" in cli_page, name
    assert "--resolution" in cli_page


def test_a_broken_link_fails_the_build(tmp_path):
    """The check is real: a page linking to a page that does not exist stops `make docs`."""
    root = tmp_path / "repo"
    shutil.copytree(REPO / "docs", root / "docs")
    shutil.copy(REPO / "mkdocs.yml", root / "mkdocs.yml")
    with (root / "docs" / "tutorial.md").open("a", encoding="utf-8") as f:
        f.write("\nSee [the missing page](nowhere.md).\n")
    r = _build(root, tmp_path / "site")
    assert r.returncode != 0 and "nowhere.md" in r.stderr, r.stderr


def test_the_readme_is_a_short_read_and_its_links_resolve():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 250
    links = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text)
    assert links
    for link in links:
        if "://" not in link:
            assert (REPO / link).exists(), link


def test_the_readme_quick_start_has_the_five_steps_in_order():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    steps = [text.index(f"foliage {cmd} ") for cmd in ("import", "inspect", "validate", "bake", "preview")]
    assert steps == sorted(steps)


def test_the_schema_page_documents_every_attribute_of_the_usd_schema():
    from pxr import Sdf

    page = (REPO / "docs" / "reference" / "schema.md").read_text(encoding="utf-8")
    layer = Sdf.Layer.FindOrOpen(str(REPO / "schemas" / "usd" / "schema.usda"))
    names = [p.name for p in layer.rootPrims if p.name != "GLOBAL"]
    assert names
    for prim in layer.rootPrims:
        if prim.name == "GLOBAL":
            continue
        assert f"## {prim.name}" in page, prim.name
        for prop in prim.properties:
            assert f"`{prop.name}`" in page, (prim.name, prop.name)


def test_the_report_page_names_every_field_of_the_json_schema():
    import json

    page = (REPO / "docs" / "reference" / "schema.md").read_text(encoding="utf-8")
    schema = json.loads((REPO / "schemas" / "json" / "report.schema.json").read_text(encoding="utf-8"))
    for field in schema["properties"]:
        assert f"| `{field}` |" in page, field


@pytest.mark.parametrize("place", USER_TEXT)
def test_no_user_text_carries_history(place):
    path = REPO / place
    files = [path] if path.is_file() else [f for f in path.rglob("*") if f.suffix in (".md", ".py", ".usda", ".json")]
    assert files, place
    found = []
    for f in files:
        for n, line in enumerate(f.read_text(encoding="utf-8").splitlines(), 1):
            if HISTORY.search(line):
                found.append(f"{f.relative_to(REPO)}:{n}: {line.strip()}")
    assert not found, "\n".join(found)
