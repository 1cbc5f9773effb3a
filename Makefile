# towerpipe — the two commands of the README:
#   make demo    set everything up (idempotent) and run the demo zone
#   make test    set everything up (idempotent) and run the test suite
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
CORES ?= 2

.PHONY: setup pdal chromium demo test lint bench train ship-models clean-demo docs-img

setup: pdal chromium $(VENV)/.installed

pdal:
	@bash scripts/install_pdal.sh

# headless Chromium: the QA pages' browser test and the screenshots of docs/img
chromium:
	@bash scripts/install_chromium.sh

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

# Screenshots of the QA pages in docs/img (after `make demo`), taken with headless Chromium at 1,280 px.
docs-img: setup
	$(BIN)/python -m towerpipe.qa.browser results/demo/qa/index.html results/demo/qa/400250_4600250.html \
	  --screenshot docs/img/qa_index.png --height 1200 --screenshot docs/img/qa_block.png --height 2100

clean-demo:
	rm -rf results/demo work/demo data/demo
