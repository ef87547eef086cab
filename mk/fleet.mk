# ------------------------------------------------------------------ fleet (issue #6)
# Included by the Makefile. A simulated week of 50 joint modules (raw/fleet/, see raw/README.md)
# through the per-unit pipeline on a local Dask cluster, then the fleet's table and report.
FLEET_RAW := raw/fleet
FLEET_CSV := $(wildcard $(FLEET_RAW)/*/*.csv)

ALL_TARGETS += fleet

.PHONY: fleet fixtures-fleet

fixtures: fixtures-fleet

fleet: results/fleet.parquet reports/fleet.pdf ## 50 simulated modules on Dask: per-unit results, fleet table and report

results/fleet.parquet reports/fleet.pdf &: $(FLEET_CSV) $(ENC_SPEC) $(CODE.fleet.fleet) | $(STAMP) ## one row per unit; reductions, out-of-family units, missing effects
	$(JC) fleet --campaigns '$(FLEET_RAW)/*' --spec $(ENC_SPEC) --out-dir results/fleet --table results/fleet.parquet --report reports/fleet.pdf

fixtures-fleet: $(STAMP) ## regenerate the simulated fleet in raw/fleet byte for byte
	$(JC) simulate fleet --out $(FLEET_RAW) --truth raw/truth/fleet --units 50 --seed 2026
