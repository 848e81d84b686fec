"""Live operator I/O for ``hydroplant play``: command sources (scripts, gamepads, Foxglove clients) and frame
sinks (the MuJoCo viewer, a live Foxglove stream), all optional and importable without their libraries until used.

- :mod:`sim.live.protocol`: the two protocols every source and sink follows;
- :mod:`sim.live.foxglove_live`: the live Foxglove stream of a run's log, and commands from Foxglove clients
  (``foxglove-sdk``);
- :mod:`sim.live.viewer`: the MuJoCo passive viewer with the cylinders and the hydraulic state overlaid;
- :mod:`sim.live.devices`: gamepad (``pygame``) and viewer-keyboard command sources;
- :mod:`sim.live.values`: the named values a sink shows, read from a plant;
- :mod:`sim.live.frame_topic`: the frame-timing topic ``/hydroplant/frame``;
- :mod:`sim.live.layout`: the Foxglove layout, generated in code and shipped as ``hydroplant-layout.json``;
- :mod:`sim.live.figures`: the documentation's pictures of the live views.
"""
