"""The virtual cell: a hidden robot that writes campaigns (simulate), measures programs (measure)
and executes corrected commands (execute)."""
