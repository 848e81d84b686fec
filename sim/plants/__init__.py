"""Plants: a scene's rigid bodies and hydraulic network stepped together.

``base`` holds what every plant shares (energy ledger, inputs, equilibrium start);
``mujoco`` / ``mujoco_fast`` step the bodies with ``mujoco.mj_step`` (per step, or in
compiled blocks); ``pbd`` steps them with :mod:`sim.xpbd`, the compiled coupling
kernels living in ``pbd_hydraulics``, ``pbd_frame`` and ``pbd_block``.
"""
