"""Independent numpy formulations of the package's compiled equations, kept as test oracles (not shipped)."""
