"""hydroplant hydraulic network (no MuJoCo import)."""
