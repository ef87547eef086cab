# jointcal: `make all` sets up .venv and runs every stage on the shipped fixtures.
# Every target below is a real file with real dependencies; `make help` lists them.

SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
JC := $(BIN)/jointcal
STAMP := $(VENV)/.installed
export SOURCE_DATE_EPOCH := 1577836800
export MPLBACKEND := Agg
export OPENBLAS_NUM_THREADS := 1

MODULES := a b
ENC_SPEC := specs/encoder_paper.toml
ENC_INTERIM := $(MODULES:%=interim/encoder/%.parquet)
ENC_HARM := $(MODULES:%=interim/encoder/%_harmonics.parquet)
ENC_ALIAS := $(MODULES:%=results/encoder/%_aliasing.csv)
ENC_ORDERS := $(MODULES:%=results/encoder/%_orders.json)
ENC_MODELS := $(MODULES:%=results/encoder/%_model.json)
ENC_TABLES := $(MODULES:%=results/encoder/%_table.csv)
SUMMARY_DEPS := $(ENC_MODELS)
ALL_TARGETS := encoder diagnosis
# diagnosis: campaign, spec and JSON name; mk/*.mk may append (DIAG_PAIRS += ...)
DIAG_PAIRS := raw/encoder/a:$(ENC_SPEC):a raw/encoder/b:$(ENC_SPEC):b

# every stage runs through the command layer and the writers: a change there reruns it
COMMON := pipeline/cli.py pipeline/io.py pipeline/errors.py

.DEFAULT_GOAL := all
.SECONDEXPANSION:
.DELETE_ON_ERROR:

-include mk/*.mk

.PHONY: all help encoder diagnosis test bench fixtures clean distclean

all: $(ALL_TARGETS) results/summary.json ## set up .venv and run the whole pipeline on raw/

help: ## list the targets
	@grep -hE '^[^#[:space:]][^=]*:.*## ' $(MAKEFILE_LIST) | sed -E -e 's/^([^ :]+)[^#]*## /\1\t/' -e 's,[$$][(]STAMP[)],.venv/.installed,' -e 's,[$$][(]BEYOND[)],results/robot/beyond,' | awk -F'\t' '{printf "  %-36s %s\n", $$1, $$2}'

$(STAMP): pyproject.toml constraints.txt ## the virtual environment with jointcal installed
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -c constraints.txt -e '.[test]'
	@touch $@

$(JC): $(STAMP)

# ------------------------------------------------------------------ encoder (paper 1)
encoder: $(ENC_TABLES) $(ENC_ALIAS) reports/encoder.pdf ## joint modules a and b: tables, report

interim/encoder/%.parquet: $$(wildcard raw/encoder/%/*.csv) $$(wildcard raw/encoder/%/campaign.toml) pipeline/ingest.py $(COMMON) | $(STAMP) ## validated readings with error_arcsec, theta_deg
	$(JC) ingest --campaign raw/encoder/$* --out $@

interim/encoder/%_harmonics.parquet: interim/encoder/%.parquet pipeline/harmonic.py $(COMMON) ## per-run harmonics (LSQ and FFT)
	$(JC) harmonic --interim $< --out $@

results/encoder/%_aliasing.csv: interim/encoder/%.parquet pipeline/aliasing.py $(COMMON) ## which orders fold into which
	$(JC) aliasing --interim $< --out $@

results/encoder/%_orders.json: interim/encoder/%.parquet interim/encoder/%_harmonics.parquet $(ENC_SPEC) pipeline/select.py $(COMMON) ## selected orders (paper rule and CV)
	$(JC) select --interim $< --harmonics interim/encoder/$*_harmonics.parquet --spec $(ENC_SPEC) --out $@

results/encoder/%_model.json: interim/encoder/%.parquet results/encoder/%_orders.json $(ENC_SPEC) pipeline/model.py pipeline/evaluate.py $(COMMON) ## model fitted on runs 1-5, evaluated on run 6
	$(JC) fit --interim $< --spec $(ENC_SPEC) --orders results/encoder/$*_orders.json --out $@

results/encoder/%_table.csv: results/encoder/%_model.json pipeline/compensate.py $(COMMON) ## compensation table every 0.1 deg
	$(JC) compensate --model $< --out $@ --step 0.1

reports/encoder.pdf: $(ENC_INTERIM) $(ENC_HARM) $(ENC_ORDERS) $(ENC_MODELS) $(ENC_ALIAS) pipeline/report.py $(COMMON) ## Figures 4-9 and numbers beside the paper's
	$(JC) report --kind encoder --out $@

results/summary.json: $(SUMMARY_DEPS) pipeline/summary.py $(COMMON) ## contract section 5
	$(JC) summary --out $@

# ------------------------------------------------------------------ diagnosis (beyond the papers)
DIAG_JSON = $(foreach p,$(DIAG_PAIRS),results/diagnosis/$(word 3,$(subst :, ,$(p))).json)
DIAG_DEPS = $(foreach p,$(DIAG_PAIRS),$(wildcard $(word 1,$(subst :, ,$(p)))/*) $(word 2,$(subst :, ,$(p))))
DIAG_ARGS = $(foreach p,$(DIAG_PAIRS),--pair $(subst :, ,$(word 1,$(subst :, ,$(p)))) $(word 2,$(subst :, ,$(p))) results/diagnosis/$(word 3,$(subst :, ,$(p))).json)

diagnosis: reports/diagnosis.pdf ## diagnose every campaign with its spec: what effect is missing

reports/diagnosis.pdf $(DIAG_JSON) &: $(DIAG_DEPS) pipeline/diagnose.py pipeline/diagnose_encoder.py pipeline/robot_diagnose.py pipeline/diagnose_report.py $(COMMON) | $(STAMP) ## residuals, candidates, waterfall
	$(JC) diagnose-all $(DIAG_ARGS) --report reports/diagnosis.pdf

# ------------------------------------------------------------------ checks and upkeep
test: $(STAMP) ## run the test suite (pytest)
	$(BIN)/python -m pytest

bench: $(STAMP) ## speed, scale, FIGAROH side by side (own venv in .bench/), 1,000-module fleet: about 7 min -> results/bench.json
	$(BIN)/python -m bench.run --out results/bench.json

fixtures: $(STAMP) $(COMMON) ## regenerate the synthetic fixtures in raw/ byte for byte
	$(JC) simulate encoder --out raw/encoder --truth raw/truth/encoder

clean: ## remove everything the pipeline made (interim/, results/, reports/)
	rm -rf interim/* results/* reports/*

distclean: clean ## also remove .venv
	rm -rf $(VENV)
