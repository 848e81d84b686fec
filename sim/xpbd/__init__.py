"""Extended Position-Based Dynamics (XPBD) for articulated rigid bodies.

Scenes are read from a compiled ``mujoco.MjModel`` (``XpbdModel.from_mjmodel``); MuJoCo is
never used for dynamics.  See ``solver.py`` for sign conventions of the length rows.
"""

from sim.xpbd.model import XpbdModel, XpbdState
from sim.xpbd.solver import LengthConstraint, SolverXPBD, SubstepForces, SubstepHooks, SubstepInputs, XpbdOptions

__all__ = [
    "XpbdModel",
    "XpbdState",
    "SolverXPBD",
    "XpbdOptions",
    "LengthConstraint",
    "SubstepInputs",
    "SubstepForces",
    "SubstepHooks",
]
