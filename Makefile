# rgbd2scene: every target works on a fresh machine (install runs first where needed).
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEMO_OUT ?= demo_out
SHELL := /bin/bash

.PHONY: install system-deps elas test demo bench lint sample docs docs-figures clean

install: $(STAMP)

# open3d needs libusb-1.0 at import time; ELAS (pyelas) is C++ built at install time; the batch gallery test loads
# ROOT/index.html in a real headless browser (Debian's chromium, about 30 s to install without the recommended
# packages). Debian-based machines get all from apt.
system-deps:
	@if ! ldconfig -p 2>/dev/null | grep -q libusb-1.0.so.0 || ! command -v g++ >/dev/null \
	    || ! command -v chromium >/dev/null; then \
	  echo "installing system packages libusb-1.0-0, g++, chromium"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0 libegl1 libgl1 libgomp1 g++ >/dev/null \
	  && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends chromium \
	    fonts-dejavu-core >/dev/null; \
	fi

$(STAMP): pyproject.toml | system-deps
	@command -v $(PY) >/dev/null || { echo "error: $(PY) not found (bpy 5.0.1 wheels need CPython 3.11)"; exit 2; }
	[ -x $(BIN)/python ] || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip setuptools wheel
	$(BIN)/pip install -q -e '.[dev]'
	$(MAKE) --no-print-directory elas
	@touch $(STAMP)

# ELAS for 'rgbd2scene evaluate' (PyPI pyelas, an sdist): it builds only without build isolation and with
# numpy's headers on the include path (setuptools and wheel are installed above). setuptools 65 passes CFLAGS to
# its C++ sources, recent ones (84) CXXFLAGS: both are set. A failure stops the install.
PYELAS := pyelas==1.0.1
elas:
	@$(BIN)/python -c "import elas" 2>/dev/null || { \
	  echo "building ELAS ($(PYELAS))"; \
	  NUMPY_INC="-I$$($(BIN)/python -c 'import numpy; print(numpy.get_include())')"; \
	  CFLAGS="$$NUMPY_INC" CXXFLAGS="$$NUMPY_INC" $(BIN)/pip install -q --no-build-isolation $(PYELAS) \
	  || { echo "error: building $(PYELAS) failed (needs a C++ compiler: apt-get install -y g++)"; exit 2; }; }

test: install
	$(BIN)/python -m pytest -q tests

# The main job on the bundled sample: capture -> scene (instrument, breathing tissue, a stereo scope with real optics:
# distortion, unequal eyes) -> the raw stereo dataset with auto exposure and sensor noise -> verified ground truth;
# then the capture's digital twin (the scope at the capture's own camera) compared with the captured image.
SAMPLE := data_samples/tissue
CAPTURE := --rgb $(SAMPLE)/rgb.png --depth $(SAMPLE)/depth.png --camera $(SAMPLE)/camera.json
# It starts afresh (its own outputs in $(DEMO_OUT) removed): after an update the scene differs, and render rightly
# refuses to resume a dataset of another scene.
DEMO_OUTPUTS := scene dataset verify.json error_maps twin_scene twin preview.png
demo: install
	rm -rf $(addprefix $(DEMO_OUT)/,$(DEMO_OUTPUTS))
	$(BIN)/rgbd2scene scene $(CAPTURE) --instrument --deform breathing \
	  --scope-calib data_samples/scope/calibration.yaml --path scan --frames 30 -o $(DEMO_OUT)/scene
	$(BIN)/rgbd2scene render $(DEMO_OUT)/scene -o $(DEMO_OUT)/dataset --frames 12
	$(BIN)/rgbd2scene verify $(DEMO_OUT)/dataset --quiet --json $(DEMO_OUT)/verify.json \
	  --error-maps $(DEMO_OUT)/error_maps
	$(BIN)/rgbd2scene scene $(CAPTURE) --path capture --no-overview -o $(DEMO_OUT)/twin_scene
	$(BIN)/rgbd2scene render $(DEMO_OUT)/twin_scene -o $(DEMO_OUT)/twin --frames 1 --quiet
	$(BIN)/rgbd2scene realism $(DEMO_OUT)/twin --real $(SAMPLE)/rgb.png --surface-only --methods none
	$(BIN)/rgbd2scene preview $(DEMO_OUT)/scene --screenshot $(DEMO_OUT)/preview.png
	@echo
	@echo "demo results in $(DEMO_OUT)/:"
	@echo "  scene/    scene.blend (open in Blender), mesh.ply, mesh.obj, overview.png, scene.json"
	@echo "  dataset/  left|right/rgb/*.png (raw, distorted, auto-exposed), left|right/gt/*.npz, sensor/*.json,"
	@echo "            calibration.yaml, dataset.json, contact_sheet.png"
	@echo "  verify.json and error_maps/ (ground-truth checks), preview.png (Open3D screenshot of the mesh)"
	@echo "  twin/realism/realism.png (the capture's digital twin beside the captured image: real, render,"
	@echo "            difference, spectra) and realism.md"

# The documentation site (mkdocs-material, API reference by mkdocstrings) into site/, warnings as errors;
# tests/test_docs.py builds it the same way and checks every page in headless Chromium.
docs: install
	NO_MKDOCS_2_WARNING=1 $(BIN)/python -m mkdocs build --strict --quiet -d site
	@echo "documentation in site/index.html"

# The site's pictures (committed): the frames drawing, and the tutorials' pictures made by the real program.
docs-figures: install
	$(BIN)/python docs/gen_frames.py
	$(BIN)/python docs/gen_figures.py

bench: install
	$(BIN)/python benchmarks/run_all.py

lint: install
	$(BIN)/ruff check rgbd2scene render tests benchmarks data_samples docs

# Regenerate the bundled sample (deterministic, seeded).
sample: install
	$(BIN)/python data_samples/make_tissue_sample.py data_samples/tissue

clean:
	rm -rf $(VENV) $(DEMO_OUT) bench_out site .pytest_cache
