# towerpipe — the two commands of the README:
#   make demo    set everything up (idempotent) and run the demo zone
#   make test    set everything up (idempotent) with a single-node SLURM, run the linters (make lint)
#                and the test suite
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
CORES ?= 2

.PHONY: setup pdal slurm chromium gdal36 demo test lint bench train benchmark-realshape ship-models clean-demo docs-img

setup: pdal chromium gdal36 $(VENV)/.installed

pdal:
	@bash scripts/install_pdal.sh

# A single-node SLURM for the cluster test (tests/workflow/test_slurm.py starts it with scripts/slurm_local.sh).
slurm:
	@bash scripts/install_slurm.sh

# headless Chromium: the QA pages' browser test and the screenshots of docs/img
chromium:
	@bash scripts/install_chromium.sh

# GDAL 3.6 (QGIS LTR of Debian 12) unpacked in build/gdal36: the tests open the GeoPackages with it
gdal36:
	@bash scripts/gdal36_tools.sh

$(VENV)/.installed: requirements.txt pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -r requirements.txt
	$(BIN)/python -m pip install -q --no-deps -e .
	touch $@

demo: setup
	$(BIN)/snakemake --cores $(CORES) results/demo/

test: setup slurm lint
	$(BIN)/python -m pytest -q

# ruff (src, tests, workflow scripts; pyproject.toml), snakefmt (Snakefile and rules), Snakemake's own lint
lint: setup
	$(BIN)/ruff check src tests workflow scripts
	$(BIN)/ruff format --check src tests workflow scripts
	$(BIN)/snakefmt --check workflow/
	$(BIN)/snakemake --lint

bench: setup
	$(BIN)/python -m towerpipe.bench preprocess
	$(BIN)/python -m towerpipe.bench e2e

# The shipped models (towerpipe.model.cards.MODEL_RELEASES): one per feature set, each trained by
# the workflow from the windows of the training zones (config/models.yaml).
MODELS := towerpipe-geometry-v3 towerpipe-shape-v3
# The shape verifier of the tower rules (towerpipe.towers.shape.VERIFIER_RELEASE): one for every model.
VERIFIER := towerpipe-verifier-v2

# Train the shipped models and the shape verifier (CPU, 2 cores).
train: setup
	$(BIN)/snakemake --cores $(CORES) $(foreach m,$(MODELS),results/models/$(m)/) work/verifiers/$(VERIFIER)

# The real-shape benchmark: every recipe trained without each real tower family and judged on it.
benchmark-realshape: setup
	$(BIN)/snakemake --cores $(CORES) results/benchmark/realshape/

# Copy trained checkpoints + model cards into models/ (what inference uses), with the benchmark's
# transfer scores in their cards (what inference.model: auto ranks by).
ship-models:
	for m in $(MODELS); do mkdir -p models/$$m && \
	  cp results/models/$$m/{classifier.pt,segmenter.pt,classifier.folded.npz,segmenter.folded.npz,model_card.json,MODEL_CARD.md,metrics.json,classifier_curves.png,segmenter_curves.png} models/$$m/; done
	$(BIN)/towerpipe realshape-stamp --scores results/benchmark/realshape/scores.json
	mkdir -p models/$(VERIFIER) && cp work/verifiers/$(VERIFIER)/{verifier.json,MODEL_CARD.md} models/$(VERIFIER)/

# Screenshots of the QA pages in docs/img (after `make demo`), taken with headless Chromium at 1,280 px.
docs-img: setup
	$(BIN)/python -m towerpipe.products.qa.browser results/demo/qa/index.html results/demo/qa/400250_4600250.html \
	  --screenshot docs/img/qa_index.png --height 1200 --screenshot docs/img/qa_block.png --height 2100

clean-demo:
	rm -rf results/demo work/demo data/demo
