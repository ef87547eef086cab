# ------------------------------------------------------------------ robot (paper 2, issue #3)
# Included by the Makefile. Real files with real dependencies; `make robot` runs the chain.
ROBOT := kr210
ROBOT_RAW := raw/robot/$(ROBOT)
ROBOT_TOML := $(ROBOT_RAW)/robot.toml
ROBOT_SPEC := specs/robot_paper.toml
ROBOT_INTERIM := interim/robot/poses.parquet
ROBOT_RES := results/robot
ROBOT_ARGS := --interim $(ROBOT_INTERIM) --robot $(ROBOT_TOML)
# the problems are small: one BLAS thread is faster and steadier than many spinning ones
ROBOT_ENV := OPENBLAS_NUM_THREADS=1

ALL_TARGETS += robot
SUMMARY_DEPS += $(ROBOT_RES)/table2.json $(ROBOT_RES)/beyond/table2.json $(ROBOT_SPEC) specs/robot_beyond.toml

.PHONY: robot fixtures-robot

fixtures: fixtures-robot

robot: $(ROBOT_RES)/table2.json $(ROBOT_RES)/closed_loop.json reports/robot.pdf ## robot chain: MDH, Chebyshev, mapping, loop, Table 2, report

interim/robot/poses.parquet: $(ROBOT_RAW)/poses.csv $(ROBOT_RAW)/tracker.csv $(ROBOT_TOML) $(CODE.campaign.ingest) | $(STAMP) ## validated robot poses joined with tracker points
	$(ROBOT_ENV) $(JC) ingest --campaign $(ROBOT_RAW) --out $@

results/robot/mdh.json: $(ROBOT_INTERIM) $(ROBOT_SPEC) $(CODE.robot.calibrate_cmd) | $(STAMP) ## MDH calibration (Eqs. 3-6) + identifiability
	$(ROBOT_ENV) $(JC) robot calibrate $(ROBOT_ARGS) --spec $(ROBOT_SPEC) --out $@

results/robot/chebyshev.json: $(ROBOT_INTERIM) $(ROBOT_SPEC) $(CODE.robot.chebyshev_cmd) | $(STAMP) ## Chebyshev model, improved L-M vs scipy
	$(ROBOT_ENV) $(JC) robot chebyshev $(ROBOT_ARGS) --spec $(ROBOT_SPEC) --out $@

results/robot/corrected_targets.csv: $(ROBOT_INTERIM) $(ROBOT_RES)/chebyshev.json $(CODE.robot.map_joints_cmd) | $(STAMP) ## joint mapping of the targets (Eqs. 22-24)
	$(ROBOT_ENV) $(JC) robot map-joints $(ROBOT_ARGS) --spec $(ROBOT_SPEC) --model $(ROBOT_RES)/chebyshev.json --out $@

results/robot/closed_loop.json: $(ROBOT_INTERIM) $(ROBOT_RES)/corrected_targets.csv $(CODE.robot.closed_loop_cmd) | $(STAMP) ## grating closed loop on the virtual cell (Eq. 26)
	$(ROBOT_ENV) $(JC) robot closed-loop $(ROBOT_ARGS) --corrected $(ROBOT_RES)/corrected_targets.csv --out $@

results/robot/table2.json: $(ROBOT_INTERIM) $(ROBOT_RES)/mdh.json $(ROBOT_RES)/corrected_targets.csv $(CODE.robot.evaluate_cmd) | $(STAMP) ## Table 2, per-target errors, ISO 9283 vAP
	$(ROBOT_ENV) $(JC) robot evaluate $(ROBOT_ARGS) --spec $(ROBOT_SPEC) --mdh $(ROBOT_RES)/mdh.json --corrected $(ROBOT_RES)/corrected_targets.csv --out $@

# beyond the paper: its method + what diagnosis finds missing (backlash of joints 4-6)
BEYOND_SPEC := specs/robot_beyond.toml
BEYOND := $(ROBOT_RES)/beyond

$(BEYOND)/chebyshev.json: $(ROBOT_INTERIM) $(BEYOND_SPEC) $(CODE.robot.chebyshev_cmd) | $(STAMP) ## feedback-stage model + backlash 4-6
	$(ROBOT_ENV) $(JC) robot chebyshev $(ROBOT_ARGS) --spec $(BEYOND_SPEC) --out $@

$(BEYOND)/corrected_targets.csv: $(ROBOT_INTERIM) $(BEYOND)/chebyshev.json $(CODE.robot.map_joints_cmd) | $(STAMP) ## its joint mapping
	$(ROBOT_ENV) $(JC) robot map-joints $(ROBOT_ARGS) --spec $(BEYOND_SPEC) --model $(BEYOND)/chebyshev.json --out $@

$(BEYOND)/table2.json: $(ROBOT_INTERIM) $(ROBOT_RES)/mdh.json $(BEYOND)/corrected_targets.csv $(CODE.robot.evaluate_cmd) | $(STAMP) ## Table 2 beyond the paper
	$(ROBOT_ENV) $(JC) robot evaluate $(ROBOT_ARGS) --spec $(BEYOND_SPEC) --mdh $(ROBOT_RES)/mdh.json --corrected $(BEYOND)/corrected_targets.csv --out $@

reports/robot.pdf: $(ROBOT_RES)/table2.json $(ROBOT_RES)/mdh.json $(ROBOT_RES)/chebyshev.json $(ROBOT_RES)/closed_loop.json $(BEYOND)/table2.json results/diagnosis/$(ROBOT).json $(CODE.robot.report_cmd) | $(STAMP) ## Figures 6-11 and Table 2 beside the paper's, and beyond it
	$(ROBOT_ENV) $(JC) robot report --results $(ROBOT_RES) --beyond $(BEYOND)/table2.json --diagnosis results/diagnosis/$(ROBOT).json --out $@

fixtures-robot: $(STAMP) ## regenerate raw/robot/kr210 poses.csv, tracker.csv and the truth byte for byte
	$(ROBOT_ENV) $(JC) simulate robot --campaign $(ROBOT_RAW) --truth raw/truth/robot/$(ROBOT).json

# the robot campaign is diagnosed with the paper's spec too (reports/diagnosis.pdf)
DIAG_PAIRS += $(ROBOT_RAW):$(ROBOT_SPEC):$(ROBOT)
