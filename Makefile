# The two commands: `make demo` (the main job on the bundled example) and
# `make test`. Both bootstrap what is missing first (`make setup`).
VENV    := .venv
PY      := $(VENV)/bin/python
FOLIAGE := $(VENV)/bin/foliage
STAMP   := $(VENV)/.installed
EXAMPLE := examples/tree_small.usda
DEMO    := out/demo
OAK     := ../shared/assets/webots_oak/oak.usda

.PHONY: setup setup-bpy demo lint test test-dcc test-slow docs bench clean

setup: $(STAMP)

$(STAMP): pyproject.toml scripts/bootstrap.sh
	@scripts/bootstrap.sh

demo: setup
	@mkdir -p $(DEMO)
	$(FOLIAGE) inspect $(EXAMPLE)
	$(FOLIAGE) validate $(EXAMPLE)
	$(FOLIAGE) bake $(EXAMPLE) -o $(DEMO) --with-reference
	$(FOLIAGE) validate $(DEMO)/tree_small.lb.usda
	@echo "demo outputs are in $(DEMO)/: tree_small.lb.usda (the whole bake over the example), .vdb grids, bench.json, bench.png and tree_small.ref.usda (the reference over the bake)"

# pyflakes, bugbear and no print() in the package ([tool.ruff] in pyproject.toml); part of `make test`
lint: setup
	$(PY) -m ruff check foliage_tools cli tests benchmarks examples scripts
	$(PY) -m mypy

# the default suite in TEST_WORKERS processes, whole test files each (module fixtures are built once)
TEST_WORKERS ?= 2
test: setup lint
	$(PY) -m pytest -m "not slow and not dcc" -q -n $(TEST_WORKERS) --dist loadfile

# the DCC round trip (issue #17): bakes imported into Blender, from the bpy venv it makes first (~350 MB once)
test-dcc: setup setup-bpy
	$(PY) -m pytest -m dcc -q

# Blender as a Python module (bpy, ~350 MB) in its own venv: bpy pins its own Python (3.11 for Blender 5.0)
# and numpy, so it cannot share .venv. tests/integration/test_blender_roundtrip.py runs Blender from it in a
# subprocess (or from $$FOLIAGE_BPY_PYTHON), and is skipped, saying so, without it.
BPY_VENV := .venv-bpy
setup-bpy: $(BPY_VENV)/.installed

$(BPY_VENV)/.installed:
	python3.11 -m venv $(BPY_VENV)
	$(BPY_VENV)/bin/pip install "bpy==5.0.*"
	@touch $@

test-slow: setup
	$(PY) -m pytest -m slow -q

# the documentation (mkdocs.yml; the CLI reference generated from the click commands by mkdocs-click) into
# site/ (git-ignored); --strict turns every warning, a broken link between pages included, into a failure
docs: setup
	$(PY) -m mkdocs build --strict --site-dir site

# Speed studies (not tests): each script prints its own table. Run one with
# `make bench BENCH=density` (density, lb, lb_issue, lb_storage, lb_grid_precision, smax, reference, reference_noise, direct, preview, spp_tables, sppg, forest, batch).
BENCH ?= density lb lb_issue lb_storage smax reference reference_noise direct preview spp_tables sppg forest batch
bench: setup
	@for b in $(BENCH); do \
	  if [ -f benchmarks/bench_$$b.py ]; then echo "== benchmarks/bench_$$b.py"; $(PY) benchmarks/bench_$$b.py || exit 1; fi; \
	done
	@echo "== speed vs error on the example (foliage bench)"
	$(FOLIAGE) bench $(EXAMPLE)
	@if [ -f $(OAK) ]; then echo "== speed vs error on the Webots oak (foliage bench)"; $(FOLIAGE) bench $(OAK); fi

clean:
	rm -rf out site .pytest_cache
