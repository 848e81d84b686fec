"""Analysis commands: inspect, reference, compare, trade-off, stability, sweeps and the hydraulics-only demo;
docgen writes the reference pages of docs/ from the code."""
