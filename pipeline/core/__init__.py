"""Shared core: input errors, atomic files, validated tables, specs, the effect base class and
registry, cross-validated residuals, plotting. Imports no other part of the package."""
