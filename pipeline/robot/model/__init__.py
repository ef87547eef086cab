"""The error model and its estimation: the MDH design and solvers (calibrate, lm, chebyshev), a spec's
effects fitted and cross-validated (estimate, fit), predictions, budgets, noise and wild points."""
