"""Analysis commands: inspect, reference, compare, trade-off, stability, sweeps and the hydraulics-only demo."""
