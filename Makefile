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
# OpenBLAS picks its kernels by the CPU it finds, and kernels differ in their last bits: on an AVX-512
# machine (SkylakeX kernels) 35 of make all's files came out other bytes than on an AVX2 one (Haswell/Zen
# kernels, which wrote tests/data/make-all.sha256). Every x86-64 CPU with AVX2 and FMA runs the Haswell
# kernels, so make uses those there and the same inputs give the same bytes on either (measured: the
# robot fit's JSON is the reference's with Haswell or Zen, other bytes with SkylakeX or Cooperlake).
# numpy, too, runs its element-wise functions (sin, exp, ...) on AVX-512 where the CPU has it: with the
# Haswell kernels alone, reports/real.pdf still came out other bytes; with AVX-512 off in numpy as well,
# the reference's (measured on an AMD EPYC with AVX-512).
ifneq ($(shell grep -qw avx2 /proc/cpuinfo 2>/dev/null && grep -qw fma /proc/cpuinfo && echo yes),)
export OPENBLAS_CORETYPE := Haswell
export NPY_DISABLE_CPU_FEATURES := X86_V4 AVX512_ICL AVX512_SPR
endif
# glibc's malloc gives freed blocks over its (moving) threshold back to the system and trims its heap;
# the robot fits free and allocate large arrays over and over, so page faults (system time) come and
# go with what the process ran before: one robot diagnosis took 6 s with these fixed thresholds and
# 9 to 19 s without (measured), the tests' 4 s or 13 s from one run to the next. Same results.
export MALLOC_MMAP_THRESHOLD_ := 33554432
export MALLOC_TRIM_THRESHOLD_ := 268435456

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

# The code a stage runs: CODE.<module>.<command> lists the pipeline/ files the command <command>
# of pipeline/cli/<module>.py may import (mk/deps.py follows the package's import statements);
# mk/deps.mk is rewritten whenever a module changes (or one is added or removed), before any
# stage is considered, so editing any module a stage uses reruns that stage.
PIPELINE_PY := $(sort $(shell find pipeline -name '*.py' -not -path '*/__pycache__/*'))

.DEFAULT_GOAL := all
.SECONDEXPANSION:
.DELETE_ON_ERROR:

mk/deps.mk: mk/deps.py $(PIPELINE_PY) $(sort $(dir $(PIPELINE_PY)))
	@$(PYTHON) mk/deps.py > $@.tmp && mv $@.tmp $@

-include mk/deps.mk
-include $(filter-out mk/deps.mk,$(wildcard mk/*.mk))

.PHONY: all help encoder diagnosis test bench bench-series fixtures reference clean distclean

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

interim/encoder/%.parquet: $$(wildcard raw/encoder/%/*.csv) $$(wildcard raw/encoder/%/campaign.toml) $(CODE.campaign.ingest) | $(STAMP) ## validated readings with error_arcsec, theta_deg
	$(JC) ingest --campaign raw/encoder/$* --out $@

interim/encoder/%_harmonics.parquet: interim/encoder/%.parquet $(CODE.encoder.harmonic) ## per-run harmonics (LSQ and FFT)
	$(JC) harmonic --interim $< --out $@

results/encoder/%_aliasing.csv: interim/encoder/%.parquet $(CODE.encoder.aliasing) ## which orders fold into which
	$(JC) aliasing --interim $< --out $@

results/encoder/%_orders.json: interim/encoder/%.parquet interim/encoder/%_harmonics.parquet $(ENC_SPEC) $(CODE.encoder.select) ## selected orders (paper rule and CV)
	$(JC) select --interim $< --harmonics interim/encoder/$*_harmonics.parquet --spec $(ENC_SPEC) --out $@

results/encoder/%_model.json: interim/encoder/%.parquet results/encoder/%_orders.json $(ENC_SPEC) $(CODE.campaign.fit) ## model fitted on runs 1-5, evaluated on run 6
	$(JC) fit --interim $< --spec $(ENC_SPEC) --orders results/encoder/$*_orders.json --out $@

results/encoder/%_table.csv: results/encoder/%_model.json $(CODE.encoder.compensate) ## compensation table every 0.1 deg
	$(JC) compensate --model $< --out $@ --step 0.1

reports/encoder.pdf: $(ENC_INTERIM) $(ENC_HARM) $(ENC_ORDERS) $(ENC_MODELS) $(ENC_ALIAS) $(CODE.encoder.report) ## Figures 4-9 and numbers beside the paper's
	$(JC) report --kind encoder --out $@

results/summary.json: $(SUMMARY_DEPS) $(CODE.summary.summary) ## contract section 5
	$(JC) summary --out $@

# ------------------------------------------------------------------ diagnosis (beyond the papers)
DIAG_JSON = $(foreach p,$(DIAG_PAIRS),results/diagnosis/$(word 3,$(subst :, ,$(p))).json)
DIAG_DEPS = $(foreach p,$(DIAG_PAIRS),$(wildcard $(word 1,$(subst :, ,$(p)))/*) $(word 2,$(subst :, ,$(p))))
DIAG_ARGS = $(foreach p,$(DIAG_PAIRS),--pair $(subst :, ,$(word 1,$(subst :, ,$(p)))) $(word 2,$(subst :, ,$(p))) results/diagnosis/$(word 3,$(subst :, ,$(p))).json)

diagnosis: reports/diagnosis.pdf ## diagnose every campaign with its spec: what effect is missing

reports/diagnosis.pdf $(DIAG_JSON) &: $(DIAG_DEPS) $(CODE.diagnose.diagnose_all) | $(STAMP) ## residuals, candidates, waterfall
	$(JC) diagnose-all $(DIAG_ARGS) --report reports/diagnosis.pdf

# ------------------------------------------------------------------ checks and upkeep
# the suite on TEST_WORKERS processes (pytest-xdist), a test file per process: on CI's two cores it takes
# about half the time of one process (module fixtures are computed once per file)
TEST_WORKERS ?= 2

test: $(STAMP) ## check the import contracts (lint-imports, .importlinter), then run the test suite (pytest, TEST_WORKERS=2 processes)
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile

bench: $(STAMP) ## speed, scale, FIGAROH side by side (own venv in .bench/), 1,000-module fleet: about 7 min -> results/bench.json
	$(BIN)/python -m bench.run --out results/bench.json

# a user's own series, timed as a user runs it (import, fit cold and cached, predict, diagnose-loop; bench/user_series.py)
bench-series: $(STAMP) ## time your series: make bench-series SERIES=export.csv SERIES_MAP=map.toml SERIES_ROBOT=robot.toml [SERIES_OTHER=campaign] -> results/bench-series.json
	@test -n "$(SERIES)" -a -n "$(SERIES_MAP)" -a -n "$(SERIES_ROBOT)" || { echo "make bench-series needs SERIES=, SERIES_MAP= and SERIES_ROBOT= (SERIES_OTHER= optional)" >&2; exit 2; }
	$(BIN)/python -m bench.user_series --source $(SERIES) --map $(SERIES_MAP) --robot $(SERIES_ROBOT) $(if $(SERIES_OTHER),--other $(SERIES_OTHER)) --out results/bench-series.json

# the reproducibility test compares one `make all` with tests/data/make-all.sha256 (mk/reference.py): a change
# meant to change what `make all` writes (or a merge of one) rewrites it here, and its commit says which files
reference: $(STAMP) ## run `make all` in a scratch copy and rewrite tests/data/make-all.sha256, the bytes make test expects
	$(BIN)/python mk/reference.py make

fixtures: $(STAMP) ## regenerate the synthetic fixtures in raw/ byte for byte
	$(JC) simulate encoder --out raw/encoder --truth raw/truth/encoder

clean: ## remove everything the pipeline made (interim/, results/, reports/)
	rm -rf interim/* results/* reports/*

distclean: clean ## also remove .venv
	rm -rf $(VENV)
