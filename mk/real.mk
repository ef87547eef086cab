# ------------------------------------------------------------------ real robot (issue #10)
# Included by the Makefile. Real laser-tracker measurements of a UR10 (raw/real/ur10-ipa, MIT,
# Landgraf et al. 2021; see its README): both series imported as published with one map, each
# fitted (geometry + base + tool, and the second paper's spec), judged on its own held-out poses
# and applied to the other series after re-registering the tracker (jointcal predict --register).
# The probe is a 6-DoF T-Mac (issue 30): the map reads its orientation, every fit weighs it against the
# position, and every predict also gives the error of a point 300 mm out along the probe's z.
REAL_RAW := raw/real/ur10-ipa
REAL_SERIES := B C
REAL_SRC_B := $(REAL_RAW)/Series_B/measurements_joint_configurations.csv
REAL_SRC_C := $(REAL_RAW)/Series_C/measurements_random_poses.csv
REAL_SPECS := kinematic paper diagnosed
REAL_RES := results/real
other = $(if $(filter B,$(1)),C,B)
# the data set, under the report's title (a user's own robot has none)
REAL_NOTE := Data: a UR10 measured by a laser tracker with a 6-DoF T-Mac probe (raw/real/ur10-ipa, Landgraf et al. 2021); a standard kinematic calibration of it is reported at about 0.45-0.48 mm RMS on held-out poses (the data set's README).

ALL_TARGETS += real
SUMMARY_DEPS += $(REAL_RES)/transfer.json
REAL_FITS := $(foreach s,$(REAL_SERIES),$(foreach m,$(REAL_SPECS),$(REAL_RES)/$(s)_$(m).json))
REAL_SELF := $(foreach s,$(REAL_SERIES),$(foreach m,$(REAL_SPECS),$(REAL_RES)/$(s)_$(m)_self.json))
REAL_XFER := $(foreach s,$(REAL_SERIES),$(foreach m,$(REAL_SPECS),$(REAL_RES)/$(s)_$(m)_on_$(call other,$(s)).json))
REAL_LOOPS := $(foreach s,$(REAL_SERIES),$(REAL_RES)/$(s)_loop.json)
REAL_DIAGNOSED := $(foreach s,$(REAL_SERIES),$(REAL_RES)/$(s)_diagnosed.toml)

.PHONY: real
.SECONDARY: $(REAL_DIAGNOSED)

real: reports/real.pdf $(REAL_RES)/transfer.json $(REAL_DIAGNOSED) ## real UR10: import both series, fit, held-out and cross-series errors, report

interim/real/%/poses.csv: $$(REAL_SRC_$$*) $(REAL_RAW)/map.toml $(REAL_RAW)/robot.toml $(CODE.importer.import_cmd) | $(STAMP) ## imported real series (robot.toml, poses.csv, tracker.csv, campaign.toml)
	$(JC) import --source $(REAL_SRC_$*) --map $(REAL_RAW)/map.toml --robot $(REAL_RAW)/robot.toml --out interim/real/$*

$(REAL_RES)/%_kinematic.json: interim/real/%/poses.csv specs/robot_kinematic.toml $(CODE.campaign.fit) | $(STAMP) ## geometry + base + tool fitted on a series' sample poses
	$(JC) fit --campaign interim/real/$* --spec specs/robot_kinematic.toml --out $@

$(REAL_RES)/%_paper.json: interim/real/%/poses.csv $(ROBOT_SPEC) $(CODE.campaign.fit) | $(STAMP) ## the second paper's model fitted on a series' sample poses
	$(JC) fit --campaign interim/real/$* --spec $(ROBOT_SPEC) --out $@

# issue #12: the user's loop on each series (diagnose, add what is recommended, diagnose again),
# each round also judged on the other series; the spec it ends with is fitted like the others
$(REAL_RES)/%_loop.json $(REAL_RES)/%_diagnosed.toml &: interim/real/%/poses.csv interim/real/$$(call other,$$*)/poses.csv specs/robot_kinematic.toml $(CODE.robot.diagnose_loop_cmd) | $(STAMP) ## diagnosis loop from geometry + base + tool until nothing is recommended
	$(JC) robot diagnose-loop --campaign interim/real/$* --spec specs/robot_kinematic.toml --other interim/real/$(call other,$*) --json $(REAL_RES)/$*_loop.json --spec-out $(REAL_RES)/$*_diagnosed.toml

$(REAL_RES)/%_diagnosed.json: $(REAL_RES)/%_diagnosed.toml interim/real/%/poses.csv $(CODE.campaign.fit) | $(STAMP) ## the spec the diagnosis loop ended with, fitted on a series' sample poses
	$(JC) fit --campaign interim/real/$* --spec $< --out $@

$(REAL_RES)/%_self.json: $(REAL_RES)/%.json $(CODE.robot.predict_cmd) | $(STAMP) ## a fit's error on each held-out pose of its own series
	$(JC) predict --campaign interim/real/$(firstword $(subst _, ,$*)) --model $< --json $@ --point "0 0 300"

# <series>_<spec>_on_<other>.json: the model of one series on the other, tracker re-registered
define REAL_TRANSFER
$(REAL_RES)/$(1)_$(2)_on_$(3).json: $(REAL_RES)/$(1)_$(2).json interim/real/$(3)/poses.csv $(CODE.robot.predict_cmd) | $(STAMP)
	$(JC) predict --campaign interim/real/$(3) --model $$< --json $$@ --register --point "0 0 300"
endef
$(foreach s,$(REAL_SERIES),$(foreach m,$(REAL_SPECS),$(eval $(call REAL_TRANSFER,$(s),$(m),$(call other,$(s))))))

# issue 52: where a model holds. The series fitted together (one robot, each series its own tracker frame),
# with the spec the loop ends with when it runs on every series together (diagnose-loop --campaign B
# --campaign C: a round kept only when no series' CV rises), judged on each series' held-out poses; and
# region splits inside a series: for each joint, that spec fitted on the sample poses below the joint's 60th
# percentile, judged on every pose above it (interim/real-split/<series>_q<joint>, jointcal robot region-split)
space := $(subst ,, )
REAL_TOGETHER := $(REAL_RES)/$(subst $(space),,$(REAL_SERIES))_together
REAL_SPLIT_SERIES := C
REAL_SPLIT_JOINTS := 1 2 3 4 5 6
REAL_SPLITS := $(foreach s,$(REAL_SPLIT_SERIES),$(foreach j,$(REAL_SPLIT_JOINTS),$(REAL_RES)/$(s)_split_q$(j)))
REAL_WHERE := $(REAL_TOGETHER).json $(REAL_TOGETHER)_self.json $(foreach f,$(REAL_SPLITS),$(f).json $(f)_above.json)

$(REAL_TOGETHER)_loop.json $(REAL_TOGETHER)_diagnosed.toml &: $(foreach s,$(REAL_SERIES),interim/real/$(s)/poses.csv) specs/robot_kinematic.toml $(CODE.robot.diagnose_loop_cmd) | $(STAMP) ## the diagnosis loop on every series together (one robot, each its own tracker frame)
	$(JC) robot diagnose-loop $(foreach s,$(REAL_SERIES),--campaign interim/real/$(s)) --spec specs/robot_kinematic.toml --json $(REAL_TOGETHER)_loop.json --spec-out $(REAL_TOGETHER)_diagnosed.toml

$(REAL_TOGETHER).json: $(foreach s,$(REAL_SERIES),interim/real/$(s)/poses.csv) $(REAL_TOGETHER)_diagnosed.toml $(CODE.campaign.fit) | $(STAMP) ## every series fitted together (each its own tracker frame), the spec their loop ended with
	$(JC) fit $(foreach s,$(REAL_SERIES),--campaign interim/real/$(s)) --spec $(REAL_TOGETHER)_diagnosed.toml --out $@

$(REAL_TOGETHER)_self.json: $(REAL_TOGETHER).json $(CODE.robot.predict_cmd) | $(STAMP) ## the series fitted together, on each series' held-out poses
	$(JC) predict $(foreach s,$(REAL_SERIES),--campaign interim/real/$(s)) --model $< --json $@ --point "0 0 300"

# <series>_split_q<j>: the region split's campaign, its fit, and the fit on the poses above the split
define REAL_SPLIT
interim/real-split/$(1)_q$(2)/poses.csv: interim/real/$(1)/poses.csv $(CODE.robot.region_split_cmd) | $(STAMP)
	$(JC) robot region-split --campaign interim/real/$(1) --joint $(2) --out interim/real-split/$(1)_q$(2)

$(REAL_RES)/$(1)_split_q$(2).json: interim/real-split/$(1)_q$(2)/poses.csv $(REAL_RES)/$(1)_diagnosed.toml $(CODE.campaign.fit) | $(STAMP)
	$(JC) fit --campaign interim/real-split/$(1)_q$(2) --spec $(REAL_RES)/$(1)_diagnosed.toml --out $$@

$(REAL_RES)/$(1)_split_q$(2)_above.json: $(REAL_RES)/$(1)_split_q$(2).json $(CODE.robot.predict_cmd) | $(STAMP)
	$(JC) predict --campaign interim/real-split/$(1)_q$(2) --model $$< --json $$@ --point "0 0 300"
endef
$(foreach s,$(REAL_SPLIT_SERIES),$(foreach j,$(REAL_SPLIT_JOINTS),$(eval $(call REAL_SPLIT,$(s),$(j)))))

$(REAL_RES)/transfer.json reports/real.pdf &: $(REAL_FITS) $(REAL_SELF) $(REAL_XFER) $(REAL_LOOPS) $(REAL_WHERE) $(CODE.robot.real_report_cmd) | $(STAMP) ## nominal / kinematic / paper errors, per-pose errors against each joint, transfer between series, the series together, region splits
	$(JC) robot real-report --results $(REAL_RES) --campaigns interim/real --out-json $(REAL_RES)/transfer.json --out reports/real.pdf --note "$(REAL_NOTE)"
