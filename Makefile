# towerpipe — the two commands of the README:
#   make demo    set everything up (idempotent) and run the demo zone
#   make test    set everything up (idempotent) and run the test suite
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
CORES ?= 2

.PHONY: setup pdal gdal36 demo test lint bench train ship-models clean-demo

setup: pdal gdal36 $(VENV)/.installed

pdal:
	@bash scripts/install_pdal.sh

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

test: setup
	$(BIN)/python -m pytest -q

lint: setup
	$(BIN)/snakemake --lint

bench: setup
	$(BIN)/python -m towerpipe.bench preprocess
	$(BIN)/python -m towerpipe.bench e2e

# The release of each shipped model: towerpipe.model.MODEL_RELEASES. full-v2 continues from
# full-v1 (training.models in config/config.yaml); the recipe of geometry-v2 is defined the
# same way but not trained yet, so geometry-v1 stays the shipped geometry model.
MODELS := towerpipe-full-v2

# Retrain the shipped v2 model on the synthetic training zones (CPU: about 26 min).
train: setup
	$(BIN)/snakemake --cores $(CORES) $(foreach m,$(MODELS),results/models/$(m)/)

# Copy trained checkpoints + model cards into models/ (what inference uses by default).
ship-models:
	for m in $(MODELS); do mkdir -p models/$$m && \
	  cp results/models/$$m/{classifier.pt,segmenter.pt,model_card.json,MODEL_CARD.md,metrics.json,classifier_curves.png,segmenter_curves.png} models/$$m/; done

clean-demo:
	rm -rf results/demo work/demo data/demo
