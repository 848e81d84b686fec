"""Live operator I/O for ``hydroplant play``: command sources (scripts, gamepads, Foxglove clients) and frame
sinks (the MuJoCo viewer, a live Foxglove stream), all optional and importable without their libraries until used.

The two protocols every source and sink follows are in :mod:`sim.live.protocol`.
"""
