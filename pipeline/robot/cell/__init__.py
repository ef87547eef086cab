"""The virtual cell: a hidden robot that writes campaigns (simulate), measures programs (measure),
executes corrected commands (execute) and runs the paper's closed-loop and evaluate stages (stages)."""
