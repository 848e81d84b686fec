"""The named values a frame sink shows, in display units, read from a plant after a frame.

=============================  ==========================================================
``<cylinder>/p_cap_bar``        cap-side absolute pressure [bar]
``<cylinder>/p_rod_bar``        rod-side absolute pressure [bar]
``<cylinder>/stroke_m``         rod extension from fully retracted [m]
``<valve>/command``             spool command [-], −1..1
``<valve>/spool``               spool position [-], −1..1
=============================  ==========================================================

A paced loop adds its own (``frame/physics_ms`` …) before handing the mapping to its sinks.

Example
-------
::

    values = display_values(plant)
    values["boom_cyl/p_cap_bar"]   # e.g. 212.4
"""

from __future__ import annotations

PA_PER_BAR = 1e5


def display_values(plant) -> dict[str, float]:
    """Cylinder pressures [bar] and strokes [m], valve commands and spools [-] of ``plant``'s current state."""
    net, state = plant.network, plant.net_state
    p, x = state.node_pressure, state.actuator_position
    out: dict[str, float] = {}
    for a, cap, rod in zip(net.cylinder_actuator, net.cylinder_cap_node, net.cylinder_rod_node):
        name = net.actuator_names[a]
        out[f"{name}/p_cap_bar"] = float(p[cap]) / PA_PER_BAR
        out[f"{name}/p_rod_bar"] = float(p[rod]) / PA_PER_BAR
        out[f"{name}/stroke_m"] = float(x[a])
    for i, name in enumerate(net.valve_names):
        out[f"{name}/command"] = float(plant.control.valve_command[i])
        out[f"{name}/spool"] = float(state.valve_spool[i])
    return out


__all__ = ["display_values"]
