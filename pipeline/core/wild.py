"""The rule that names wild measurements (contract section 12), as numbers and words: kept free of
the library so that the commands' ``--help`` can state it (:mod:`pipeline.robot.model.outliers` applies it)."""

#: A pose is wild beyond this many robust standard deviations (per axis) of a flexible model's
#: residuals: twice the Gaussian bound (6 sigma in 3-D, once in 10^7 poses), as real residuals are
#: heavier tailed (docs/speed.md "Measurements behind the code").
WILD_SIGMAS = 12.0
#: The nearest sample poses (joint space, each joint scaled by its sampled range) a wild pose's
#: residual is compared with.
NEIGHBOURS = 8
#: More than this fraction of a campaign's poses wild (and more than :data:`HANDFUL`): refused.
MAX_WILD_FRACTION = 0.02
#: Up to this many wild poses are named, never refused, however small the campaign: one wild point in
#: the 20 poses ``jointcal plan`` proposes is 5 % of them, and an SMR reseated, not a wrong frame.
#: From 150 poses on, 2 % is more than this and decides alone.
HANDFUL = 3
#: The flexible model gives a scale when it leaves at least this fraction of its residuals' degrees of
#: freedom (3 a pose, less the fit's effective number of parameters: the trace of its hat matrix). On
#: fewer poses it nearly interpolates them (20 poses: sigma 4e-5 mm, every point 12 sigma off): no
#: scale, no wild point named, and the command says so and goes on.
MIN_RESIDUAL_DOF_FRACTION = 0.5

RULE = (f"a pose is wild when its 3-D residual from a robust fit of a flexible model (geometry, base, "
        f"tool, a joint map and compliance on every joint, backlash, the spec's other effects) exceeds {WILD_SIGMAS:g} robust "
        f"standard deviations (sigma = sqrt(median |r|^2 / 2.366)) and is not shared by its {NEIGHBOURS} nearest "
        f"sample poses in joint space; wild sample poses are refitted without until none changes; when the "
        f"flexible model leaves less than {100 * MIN_RESIDUAL_DOF_FRACTION:g} % of its residuals' degrees of freedom "
        f"(a small campaign it nearly interpolates) there is no scale and none is named; more than "
        f"{100 * MAX_WILD_FRACTION:g} % (and more than {HANDFUL}) of the poses wild is refused")

HELP = (f"Keep the wild measurements in the fit (they are still named). Wild measurements (contract section 12): "
        f"{RULE}. Each is named (point_id, set, tracker.csv line, size in mm) and, by default, left out of the fit "
        "and of every cross-validation; held-out errors are given without the wild targets and, beside them, "
        "with them. See docs/wild-points.md.")
