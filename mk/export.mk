# --------------------------------------------------- the model on the robot (issue #18)
# Included by the Makefile. The real UR10 series' full models (the diagnosis loop's final spec)
# exported as a URDF and judged on its series' held-out poses: the full model, what the URDF (or UR's
# parameters) carries, and URDF + joint tables (`jointcal export --heldout`; the ur and table formats
# are written the same way, see README).
# (read before mk/real.mk: literal paths here)
REAL_EXPORT := results/real/B_export.json results/real/C_export.json

results/real/%_export.json: results/real/%_diagnosed.json interim/real/%/poses.csv $(CODE.deploy.export_cmd) | $(STAMP) ## held-out RMS of the full model, of what a URDF carries, and of URDF + joint tables (real series)
	$(JC) export --model $< --format urdf --out results/real/$*_diagnosed.urdf --heldout interim/real/$* --json $@

# the real report shows them
results/real/transfer.json: $(REAL_EXPORT)

# ---------------------------------------- the job end to end on Series C (README's first example)
# the diagnosed model applied to the series' own poses as a program, and 20 poses planned from them
REAL_JOURNEY := results/real/C_corrected.csv results/real/C_plan.csv
ALL_TARGETS += $(REAL_JOURNEY)

results/real/C_corrected.csv: results/real/C_diagnosed.json interim/real/C/poses.csv $(CODE.deploy.correct) | $(STAMP) ## Series C's poses as a program, corrected with its diagnosed model
	$(JC) correct --model $< --targets interim/real/C/poses.csv --out $@

results/real/C_plan.csv results/real/C_plan.json &: interim/real/C/poses.csv specs/robot_kinematic.toml $(CODE.plan.plan_cmd) | $(STAMP) ## 20 poses planned from Series C's poses for geometry + base + tool
	$(JC) plan --robot interim/real/C/robot.toml --spec specs/robot_kinematic.toml --pool interim/real/C/poses.csv --n 20 --out results/real/C_plan.csv --json results/real/C_plan.json
