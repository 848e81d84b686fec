"""The raw sample row of a run's recorder: one float64 row per logged step, described once.

``RunRecorder.capture`` (:mod:`sim.run.recorder`) and the plants that record inside their compiled blocks
(``MujocoPlantFast.advance``, ``PbdPlant``'s ``record_next``) write a sample's raw state into one row; the
recorder derives the logged channels from its columns.  :data:`RECORD_ROW` is that row's layout
(:class:`hydraulics.layout.Layout`): its width (``record_width``), the columns of each field and the compiled
writers' views are generated from it.

Dimensions: ``n`` nodes, ``nq``/``nv`` joint coordinates and rates (MuJoCo's whole ``qpos``/``qvel``, or a
PBD plant's scalar joints), ``na`` actuators, ``nvalve`` valves, ``nstate`` component states, ``npump`` pumps,
``nb`` branches, ``nbody`` bodies, ``nctl`` controllers.

Example
-------
>>> width = RECORD_ROW.size(n=2, nq=1, nv=1, na=1, nvalve=1, nstate=1, npump=0, nb=2, nbody=2, nctl=0)
>>> width == 2 + 1 + 1 + 2 + 4 + 1 + 1 + 0 + 2 + 2 + 6 + 2 * 7
True
"""

from __future__ import annotations

from hydraulics.controllers import STATE_COLUMNS
from hydraulics.layout import Layout

RECORD_ROW = Layout("record_row", ("n", "nq", "nv", "na", "nvalve", "nstate", "npump", "nb", "nbody", "nctl"), (
    ("p", "n"),  # node pressures [Pa]
    ("qpos", "nq"), ("qvel", "nv"),  # joint positions [m | rad] and rates [m/s | rad/s]
    ("oil", "n"),  # node oil [m³ at reference density]
    ("x", "na"), ("v", "na"),  # actuator positions [m | rad] and velocities [m/s | rad/s]
    ("effort", "na"), ("theta", "na"),  # applied efforts [N | N·m], θ of the effort law [-]
    ("cmd", "nvalve"), ("spool", "nstate"),  # valve commands [-], component states (valve spools first)
    ("speed", "npump"), ("flow", "nb"),  # pump speeds [rev/s], branch flows [m³/s]
    ("solver", 2),  # Newton iterations, residual [Pa] of the last step
    ("energy", 6),  # kinetic, potential energy, pump work, hydraulic, friction, mechanical dissipation [J]
    ("xpos", "nbody", 3), ("xquat", "nbody", 4),  # body positions [m], orientations (w, x, y, z)
    ("controllers", "nctl", len(STATE_COLUMNS)),  # the controllers' states (hydraulics.controllers.STATE_COLUMNS)
))
"""The raw sample row (see module docstring); the node pressures and joints come first and adjacent (a sample's
finiteness is one sum over them)."""
