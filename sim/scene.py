"""A scene: the MJCF (geometry, inertia), the circuit (hydraulics) and their binding.

The MJCF owns geometry and inertia, the circuit owns hydraulics.  They meet by
name: each cylinder of the circuit is an MJCF ``<spatial>`` tendon and a
``<general>`` actuator of the same name (the tendon's ``range`` lower bound is
the fully retracted pin-to-pin length, and range width must equal the
circuit's stroke); each motor is an actuator of the same name on a joint
(``gear`` = motor shaft angle per joint angle).  :func:`load_scene` checks all
of this and raises :class:`~sim.scenario.ScenarioError` naming both files.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from hydraulics.circuit import load_circuit
from hydraulics.network import ACTUATOR_CYLINDER, NetworkModel

from .scenario import Scenario, ScenarioError

STROKE_TOLERANCE = 1e-3  # m: MJCF tendon range width vs circuit stroke


@dataclass(frozen=True, eq=False)
class Binding:
    """Network actuator i ↔ MuJoCo actuator ``actuator_id[i]`` (cylinder lengths offset by ``closed_length``)."""

    actuator_id: np.ndarray  # (actuator_count,) MuJoCo actuator ids
    closed_length: np.ndarray  # (actuator_count,) m for cylinders (tendon range lower bound), 0 for motors
    tendon_id: np.ndarray  # (actuator_count,) tendon id or -1


@dataclass(eq=False)
class Scene:
    """Everything a plant needs, built once per run."""

    scenario: Scenario
    mjmodel: mujoco.MjModel
    network: NetworkModel
    binding: Binding
    joint_names: tuple

    def mjcf_text(self) -> bytes:
        return Path(self.scenario.mjcf).read_bytes()


def check_masses(path: Path) -> None:
    """Reject negative masses and inertias in the MJCF text (MuJoCo's compiler silently zeroes some)."""
    import xml.etree.ElementTree as ElementTree

    try:
        root = ElementTree.parse(path).getroot()
    except (ElementTree.ParseError, OSError):
        return  # MuJoCo's compiler reports it with its own message
    for body in root.iter("body"):
        for element in [body, *body.findall("inertial"), *body.findall("geom")]:
            for attribute in ("mass", "diaginertia"):
                text = element.get(attribute)
                try:
                    values = [float(v) for v in text.split()] if text else []
                except ValueError:
                    continue
                if any(v < 0 for v in values):
                    raise ScenarioError(
                        f"{path}: body '{body.get('name', '?')}', <{element.tag}> {attribute}=\"{text}\": must be >= 0 (kg, kg*m^2)"
                    )


def load_mjmodel(path: Path) -> mujoco.MjModel:
    """Compile an MJCF, turning MuJoCo's errors into a ScenarioError naming the file."""
    check_masses(path)
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except Exception as exc:  # mujoco raises ValueError with the parser's message
        raise ScenarioError(f"{path}: MuJoCo cannot compile this MJCF: {exc}") from None


def bind(network: NetworkModel, mjmodel: mujoco.MjModel, circuit_path, mjcf_path) -> Binding:
    """Match circuit actuators to MJCF actuators by name and check strokes."""
    names = [mujoco.mj_id2name(mjmodel, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(mjmodel.nu)]
    ids, closed, tendons = [], [], []
    for a, name in enumerate(network.actuator_names):
        where = f"{circuit_path}: component '{name}'"
        aid = mujoco.mj_name2id(mjmodel, mujoco.mjtObj.mjOBJ_ACTUATOR, name)
        if aid < 0:
            raise ScenarioError(f"{where}: no actuator named '{name}' in {mjcf_path}; its actuators are {names}")
        if network.actuator_kind[a] == ACTUATOR_CYLINDER:
            if int(mjmodel.actuator_trntype[aid]) != int(mujoco.mjtTrn.mjTRN_TENDON):
                raise ScenarioError(f"{mjcf_path}: actuator '{name}' must act on a spatial tendon (the cylinder's pin-to-pin line)")
            tid = int(mjmodel.actuator_trnid[aid, 0])
            low, high = mjmodel.tendon_range[tid]
            stroke = network.cylinder_stroke[list(network.cylinder_actuator).index(a)]
            if abs((high - low) - stroke) > STROKE_TOLERANCE:
                raise ScenarioError(
                    f"{where}, field 'stroke': {stroke} m but tendon '{name}' in {mjcf_path} has range "
                    f"[{low}, {high}] (width {high - low:.4f} m); they must agree within {STROKE_TOLERANCE} m"
                )
            ids.append(aid)
            closed.append(low)
            tendons.append(tid)
        else:
            if int(mjmodel.actuator_trntype[aid]) != int(mujoco.mjtTrn.mjTRN_JOINT):
                raise ScenarioError(f"{mjcf_path}: actuator '{name}' (a motor) must act on a joint")
            ids.append(aid)
            closed.append(0.0)
            tendons.append(-1)
    return Binding(np.array(ids, int), np.array(closed, float), np.array(tendons, int))


def configure_actuators(mjmodel: mujoco.MjModel, binding: Binding) -> None:
    """Make every bound actuator a plain affine force: f = ctrl + b₂·v (no clamps, no dynamics).

    A clamped actuator (``forcerange``) would lose MuJoCo's implicit velocity
    term, so clamps are removed; the plant writes ctrl and b₂ each step.
    """
    for aid in binding.actuator_id:
        mjmodel.actuator_dyntype[aid] = mujoco.mjtDyn.mjDYN_NONE
        mjmodel.actuator_gaintype[aid] = mujoco.mjtGain.mjGAIN_FIXED
        mjmodel.actuator_biastype[aid] = mujoco.mjtBias.mjBIAS_AFFINE
        mjmodel.actuator_gainprm[aid, :] = 0.0
        mjmodel.actuator_gainprm[aid, 0] = 1.0
        mjmodel.actuator_biasprm[aid, :] = 0.0
        mjmodel.actuator_ctrllimited[aid] = 0
        mjmodel.actuator_forcelimited[aid] = 0


def has_contact_pairs(mjmodel: mujoco.MjModel) -> bool:
    """True when two geoms of different bodies can collide (contype/conaffinity) or explicit pairs exist."""
    if mjmodel.npair:
        return True
    contype, conaffinity, body = mjmodel.geom_contype, mjmodel.geom_conaffinity, mjmodel.geom_bodyid
    can = ((contype[:, None] & conaffinity[None, :]) | (conaffinity[:, None] & contype[None, :])) != 0
    return bool(np.any(can & (body[:, None] != body[None, :])))


def load_scene(scenario: Scenario) -> Scene:
    """Compile the MJCF, build the network and bind them; MJCF timestep set to the scenario's dt."""
    mjmodel = load_mjmodel(scenario.mjcf)
    network = NetworkModel.from_circuit(load_circuit(scenario.circuit), fidelity=scenario.fidelity)
    binding = bind(network, mjmodel, scenario.circuit, scenario.mjcf)
    configure_actuators(mjmodel, binding)
    mjmodel.opt.timestep = scenario.dt
    if not has_contact_pairs(mjmodel):
        mjmodel.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT  # nothing can touch: skip collision detection
    joints = tuple(mujoco.mj_id2name(mjmodel, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}" for j in range(mjmodel.njnt))
    for name in list(scenario.qpos) + list(scenario.qvel):
        if name not in joints:
            raise ScenarioError(f"{scenario.path}, [initial]: joint '{name}' is not in {scenario.mjcf}; joints: {list(joints)}")
    known_inputs = set(network.valve_names) | set(network.pump_names)
    for name in scenario.inputs:
        if name not in known_inputs:
            raise ScenarioError(
                f"{scenario.path}, field 'inputs.{name}': no valve or pump called '{name}' in {scenario.circuit}; inputs: {sorted(known_inputs)}"
            )
    for net in scenario.pressures:
        if net not in network.net_node:
            raise ScenarioError(f"{scenario.path}, field 'initial.pressures.{net}': no net '{net}' in {scenario.circuit}")
    return Scene(scenario, mjmodel, network, binding, joints)


def initial_qpos_qvel(scene: Scene):
    """qpos, qvel arrays from the model defaults and the scenario's [initial] joint values."""
    m = scene.mjmodel
    qpos = m.qpos0.copy()
    qvel = np.zeros(m.nv)
    for name, value in scene.scenario.qpos.items():
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        qpos[m.jnt_qposadr[j]] = value
    for name, value in scene.scenario.qvel.items():
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        qvel[m.jnt_dofadr[j]] = value
    return qpos, qvel
