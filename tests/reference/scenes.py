"""MJCF text shared by the tests' small scenes.

:func:`vertical_lift` is a load on a vertical slide joint (0.5 … 1.0 m) driven by one cylinder ``lift``: sites
``lift_barrel`` (world origin) and ``lift_rod`` (on the load), a spatial tendon of that range and a ``general``
actuator on it, as models/README.md describes a cylinder.  :data:`BENCH` is a test bench without any joint, for
circuits that drive no actuator.

Example
-------
>>> import mujoco
>>> float(mujoco.MjModel.from_xml_string(vertical_lift(mass=10.0)).body_mass[1])
10.0
"""

from __future__ import annotations

BENCH = """<mujoco model="bench">
  <option timestep="0.001"/>
  <worldbody><geom name="bench" type="box" size="0.3 0.2 0.02" contype="0" conaffinity="0"/></worldbody>
</mujoco>
"""
"""MJCF of a bench welded to the world: no joint, no degree of freedom."""


def vertical_lift(*, mass: float, inertia: float = 0.01, gravity: float = 9.81) -> str:
    """MJCF of a load of ``mass`` [kg] (principal inertia ``inertia`` [kg·m²]) lifted by cylinder ``lift`` under
    ``gravity`` [m/s²]."""
    return f"""<mujoco model="lift">
  <compiler angle="radian" autolimits="false"/>
  <option timestep="0.001" integrator="implicitfast" gravity="0 0 -{gravity}"/>
  <worldbody>
    <site name="lift_barrel" pos="0 0 0" size="0.01"/>
    <body name="load" pos="0 0 0">
      <joint name="z" type="slide" axis="0 0 1" limited="true" range="0.5 1.0"/>
      <inertial pos="0 0 0" mass="{mass}" diaginertia="{inertia} {inertia} {inertia}"/>
      <site name="lift_rod" pos="0 0 0" size="0.01"/>
    </body>
  </worldbody>
  <tendon>
    <spatial name="lift" limited="true" range="0.5 1.0">
      <site site="lift_barrel"/>
      <site site="lift_rod"/>
    </spatial>
  </tendon>
  <actuator>
    <general name="lift" tendon="lift" ctrllimited="false" gaintype="fixed" gainprm="1" biastype="affine" biasprm="0 0 0"/>
  </actuator>
</mujoco>
"""
