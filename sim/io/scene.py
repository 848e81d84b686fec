"""A scene: the MJCF (geometry, inertia), the circuit (hydraulics) and their binding.

The MJCF owns geometry and inertia, the circuit owns hydraulics.  They meet by
name: each cylinder of the circuit is an MJCF ``<spatial>`` tendon and a
``<general>`` actuator of the same name (the tendon's ``range`` lower bound is
the fully retracted pin-to-pin length, and range width must equal the
circuit's stroke), or an actuator on the rod's slide joint (or a ``<fixed>``
tendon over it) whose range is the stroke, driven pin to pin on the links
(:mod:`sim.io.cylinder_pins`); each motor is an actuator of the same name on a joint
(``gear`` = motor shaft angle per joint angle).  :func:`load_scene` checks all
of this and raises :class:`~sim.io.scenario.ScenarioError` naming both files.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field, replace
from pathlib import Path

import mujoco
import numpy as np

from hydraulics.circuit import load_circuit
from hydraulics.components import CircuitError
from hydraulics.files import read_bytes, read_text, resolve
from hydraulics.network import ACTUATOR_CYLINDER, NetworkModel, prune

from sim.io.cylinder_pins import STROKE_TOLERANCE, pin_cylinders
from sim.io.scenario import Scenario, ScenarioError, check_input_ranges
from sim.plants.controllers import ControllerBank



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
    model_files: tuple = field(default_factory=tuple)  # (path, bytes) of the MJCF, then its includes and assets
    warnings: tuple = ()  # what the validator found, one line each naming the MJCF element (validate_model)
    notes: tuple = ()  # how the MJCF was read where it could be read two ways (sim.io.cylinder_pins), one line each

    def mjcf_text(self) -> bytes:
        return read_bytes(self.scenario.mjcf, "MJCF", ScenarioError)


MAX_INCLUDE_DEPTH = 32  # nested <include> levels
ASSET_FILE_ATTRIBUTES = {  # MJCF elements that read a file, their file attributes and the <compiler> folder they use
    "mesh": (("file",), "meshdir"),
    "skin": (("file",), "meshdir"),
    "hfield": (("file",), "texturedir"),
    "texture": (("file", "fileright", "fileleft", "fileup", "filedown", "filefront", "fileback"), "texturedir"),
}


@dataclass(frozen=True, eq=False)
class MjcfFile:
    """One file an MJCF model is built from: its resolved path, its bytes and what it is."""

    path: Path
    data: bytes
    kind: str  # "mjcf", "include" or "asset"
    root: object = None  # the parsed XML root (mjcf and include), for checks on the text


def mjcf_files(path) -> list[MjcfFile]:
    """The MJCF at ``path``, then every file it includes (``<include file>``, nested) and every asset file it
    names (mesh, skin, hfield, texture), each read once through :func:`hydraulics.files.read_bytes`.

    Paths resolve as MuJoCo resolves them: relative to the folder of the top-level MJCF (includes
    too, at any depth), assets below ``<compiler assetdir | meshdir | texturedir>`` when set;
    folders outside the scene's are allowed.  Every file must be a regular file of bounded size;
    the XML files UTF-8 text.  An include cycle, or includes nested deeper than
    :data:`MAX_INCLUDE_DEPTH`, raise :class:`ScenarioError`.  XML that does not parse is returned
    without its includes (MuJoCo's compiler names the error).
    """
    main = resolve(path, "MJCF", ScenarioError)
    base = main.parent
    files: list[MjcfFile] = []
    seen: set[Path] = set()

    def xml_file(file: Path, kind: str, chain: tuple):
        if file in chain:
            raise ScenarioError(f"{file}: MJCF include cycle: {' -> '.join(str(p) for p in (*chain, file))}")
        if len(chain) > MAX_INCLUDE_DEPTH:
            raise ScenarioError(f"{file}: MJCF includes nested deeper than {MAX_INCLUDE_DEPTH} levels")
        text = read_text(file, "MJCF" if kind == "mjcf" else f"MJCF include (of {chain[-1]})", ScenarioError)
        try:
            root = ElementTree.fromstring(text)
        except (ElementTree.ParseError, ValueError, RecursionError):
            root = None
        if file not in seen:
            seen.add(file)
            files.append(MjcfFile(file, text.encode("utf-8"), kind, root))
        if root is None:
            return
        for element in root.iter("include"):
            name = element.get("file")
            if name:
                xml_file(resolve(base / name, f"MJCF include (of {file})", ScenarioError), "include", (*chain, file))

    xml_file(main, "mjcf", ())
    folders = {}
    for f in files:
        if f.root is not None:
            for compiler in f.root.iter("compiler"):
                folders.update({k: v for k, v in compiler.attrib.items() if k in ("assetdir", "meshdir", "texturedir")})
    for f in list(files):
        if f.root is None:
            continue
        for tag, (attributes, folder_key) in ASSET_FILE_ATTRIBUTES.items():
            folder = base / folders.get(folder_key, folders.get("assetdir", ""))
            for element in f.root.iter(tag):
                for attribute in attributes:
                    name = element.get(attribute)
                    if not name:
                        continue
                    what = f"MJCF asset <{tag} {attribute}> (of {f.path})"
                    asset = resolve(name if os.path.isabs(name) else folder / name, what, ScenarioError)
                    if asset not in seen:
                        seen.add(asset)
                        files.append(MjcfFile(asset, read_bytes(asset, what, ScenarioError), "asset"))
    return files


def input_paths(scenario: Scenario) -> list[Path]:
    """Every file a run of ``scenario`` reads: the MJCF, its includes and assets (:func:`mjcf_files`), the circuit,
    the scenario and its inputs CSV if any -- e.g. for a content hash of everything a result depends on."""
    paths = [f.path for f in mjcf_files(scenario.mjcf)] + [Path(scenario.circuit), Path(scenario.path)]
    return paths + ([Path(scenario.inputs_csv)] if scenario.inputs_csv is not None else [])


def check_masses(path: Path, root=None) -> None:
    """Reject negative, NaN or infinite masses and inertias in the MJCF text (MuJoCo's compiler silently zeroes some).

    ``root``: the parsed XML of ``path`` (read from ``path`` when None).
    """
    if root is None:
        try:
            root = ElementTree.fromstring(read_text(path, "MJCF", ScenarioError))
        except (ElementTree.ParseError, ValueError, RecursionError):
            return  # MuJoCo's compiler reports it with its own message
    for body in root.iter("body"):
        for element in [body, *body.findall("inertial"), *body.findall("geom")]:
            for attribute in ("mass", "diaginertia"):
                text = element.get(attribute)
                try:
                    values = [float(v) for v in text.split()] if text else []
                except ValueError:
                    continue
                if any(not (math.isfinite(v) and v >= 0) for v in values):
                    raise ScenarioError(
                        f"{path}: body '{body.get('name', '?')}', <{element.tag}> {attribute}=\"{text}\": "
                        "must be finite and >= 0 (kg, kg*m^2)"
                    )


def load_mjmodel(path: Path, files: list[MjcfFile] | None = None) -> mujoco.MjModel:
    """Compile an MJCF, turning MuJoCo's errors into a ScenarioError naming the file.

    ``files``: the model's files from :func:`mjcf_files` (read now when None): each is checked
    (regular file, bounded size, masses) before MuJoCo reads any of them, so that a FIFO or a
    device among the includes is refused instead of blocking the compiler.  The compiled
    model's body masses and inertias must be finite.
    """
    files = mjcf_files(path) if files is None else files
    for f in files:
        if f.root is not None:
            check_masses(f.path, f.root)
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except Exception as exc:  # mujoco raises ValueError with the parser's message
        message = " ".join(str(exc).split())  # one line
        raise ScenarioError(f"{path}: MuJoCo cannot compile this MJCF: {message}") from None
    check_finite_model(model, path)
    check_moving_masses(model, path)
    return model


MIN_MOVING_MASS = 1e-3
"""Lightest body a joint may move, with the bodies it carries [kg]: a cylinder's kN on less than a gram
accelerates it by 1e6 m/s^2 and more, which no step resolves (MuJoCo resets such a state mid-step)."""


def check_moving_masses(model: mujoco.MjModel, path) -> None:
    """Refuse a body that a joint moves whose mass with its subtree (``body_subtreemass``) is below
    :data:`MIN_MOVING_MASS`; the message names the MJCF, the body and the allowed range."""
    for b in range(1, model.nbody):
        if model.body_dofnum[b] and not float(model.body_subtreemass[b]) >= MIN_MOVING_MASS:
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"#{b}"
            raise ScenarioError(f"{path}: body '{name}': mass {float(model.body_subtreemass[b]):.4g} kg (with the bodies "
                                f"it carries) is outside the allowed range [{MIN_MOVING_MASS:g}, inf) kg for a body a "
                                "joint moves")


_MODEL_OBJECTS = {"body": mujoco.mjtObj.mjOBJ_BODY, "jnt": mujoco.mjtObj.mjOBJ_JOINT, "dof": None,
                  "geom": mujoco.mjtObj.mjOBJ_GEOM, "site": mujoco.mjtObj.mjOBJ_SITE, "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR,
                  "tendon": mujoco.mjtObj.mjOBJ_TENDON, "eq": mujoco.mjtObj.mjOBJ_EQUALITY, "pair": mujoco.mjtObj.mjOBJ_PAIR}


_MODEL_FIELDS_FIRST = ("body_mass", "body_inertia", "dof_armature", "dof_damping", "dof_frictionloss", "jnt_stiffness",
                       "jnt_range", "geom_size", "geom_friction", "actuator_gear", "tendon_range")  # what the MJCF sets


def check_finite_model(model: mujoco.MjModel, path) -> None:
    """Refuse a compiled model with a NaN or infinite number in any of its arrays (a mass, an inertia, an
    armature, a damping, a size, ...): MuJoCo compiles some of them silently and the run fails later.
    The message names the MJCF, the model field (MuJoCo's name, e.g. ``dof_armature``) and the element."""
    for field_name in (*_MODEL_FIELDS_FIRST, *dir(model)):
        if field_name.startswith("_") or field_name == "opt":
            continue
        try:
            values = getattr(model, field_name)
        except Exception:  # noqa: BLE001 - properties MuJoCo cannot give for this model
            continue
        if not (isinstance(values, np.ndarray) and values.dtype.kind == "f" and values.size):
            continue
        bad = np.flatnonzero(~np.isfinite(values.reshape(len(values), -1)).all(axis=1)) if values.ndim else []
        if len(bad) == 0:
            continue
        prefix, index = field_name.split("_", 1)[0], int(bad[0])
        if prefix == "dof":
            prefix, index = "jnt", int(model.dof_jntid[index])
        obj = _MODEL_OBJECTS.get(prefix)
        name = (mujoco.mj_id2name(model, obj, index) if obj is not None else None) or f"#{index}"
        kind = {"jnt": "joint", "eq": "equality"}.get(prefix, prefix)
        raise ScenarioError(f"{path}: {kind} '{name}': a NaN or infinite value in '{field_name}' after compilation; "
                            "every number of the model must be finite")


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
            tid = check_cylinder_transmission(mjmodel, aid, name, mjcf_path)
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


def check_cylinder_transmission(mjmodel: mujoco.MjModel, aid: int, name: str, mjcf_path) -> int:
    """The tendon id of cylinder actuator ``aid``; refuses (both modes) any transmission but a two-site spatial tendon.

    A cylinder is its pin-to-pin line: a ``<spatial>`` tendon through exactly two
    sites, one at the barrel pin and one at the rod eye (on the barrel and rod
    bodies of a model that has them, or on the links).  A ``<fixed>`` tendon or a
    joint transmission (the rod's slide) is refused with the change to make.
    """
    fix = (f"; give it a <spatial> tendon through two sites, one at the barrel pin and one at the rod eye (on the barrel "
           f"and rod bodies if the model has them), with range = [closed pin-to-pin length, closed length + stroke] [m], "
           f"or put the actuator on the rod's slide joint, whose range is then the stroke")
    trn = int(mjmodel.actuator_trntype[aid])
    target = int(mjmodel.actuator_trnid[aid, 0])
    if trn == int(mujoco.mjtTrn.mjTRN_JOINT):
        joint = mujoco.mj_id2name(mjmodel, mujoco.mjtObj.mjOBJ_JOINT, target) or str(target)
        raise ScenarioError(f"{mjcf_path}: actuator '{name}' (a cylinder) acts on joint '{joint}'" + fix)
    if trn != int(mujoco.mjtTrn.mjTRN_TENDON):
        kind = mujoco.mjtTrn(trn).name.removeprefix("mjTRN_").lower()
        raise ScenarioError(f"{mjcf_path}: actuator '{name}' (a cylinder) has a {kind} transmission" + fix)
    tendon = mujoco.mj_id2name(mjmodel, mujoco.mjtObj.mjOBJ_TENDON, target) or str(target)
    adr, num = int(mjmodel.tendon_adr[target]), int(mjmodel.tendon_num[target])
    wraps = [int(w) for w in mjmodel.wrap_type[adr : adr + num]]
    if any(w == int(mujoco.mjtWrap.mjWRAP_JOINT) for w in wraps):
        raise ScenarioError(f"{mjcf_path}: actuator '{name}' (a cylinder) acts on <fixed> tendon '{tendon}' (a sum of joints)" + fix)
    if wraps != [int(mujoco.mjtWrap.mjWRAP_SITE)] * 2:
        raise ScenarioError(
            f"{mjcf_path}: actuator '{name}' (a cylinder) acts on spatial tendon '{tendon}' with {num} path elements "
            "(sites, geoms or pulleys)" + fix
        )
    return target


PBD_MODES = ("pbd", "pbd-naive")
PBD_CONTACT_GEOMS = tuple(int(t) for t in (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_SPHERE,
                                           mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_BOX))
PBD_EQUALITIES = (int(mujoco.mjtEq.mjEQ_CONNECT), int(mujoco.mjtEq.mjEQ_WELD))


def _name(mjmodel, objtype, i) -> str:
    return mujoco.mj_id2name(mjmodel, objtype, int(i)) or f"#{int(i)}"


def validate_model(mjmodel: mujoco.MjModel, binding: Binding, scenario: Scenario) -> tuple:
    """Warnings for what the model holds beyond the circuit and the chosen mode; refuses what a mode cannot step.

    Both modes: MJCF actuators the circuit does not drive (set to zero force in
    both, so a leftover ``<velocity>`` actuator brakes nothing).  PBD mode: a
    body with more than one joint, or a free joint below another body, is
    refused (:class:`ScenarioError`); free joints (a base welded to the world),
    colliding geoms other than planes, spheres, capsules and boxes, equalities
    other than connect and weld, and joint frictionloss / stiffness are named
    in warnings.  Returns the warnings (one line each, MJCF names).
    """
    m, mjcf = mjmodel, scenario.mjcf
    out = []
    unused = [a for a in range(m.nu) if a not in set(int(i) for i in binding.actuator_id)]
    if unused:
        names = ", ".join(f"'{_name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a)}'" for a in unused)
        out.append(
            f"{mjcf}: actuator(s) {names} are not driven by {scenario.circuit}: they are set to zero force in both modes "
            "(a <velocity> or <position> actuator left in would brake or hold its joint); delete them from the MJCF"
        )
    if scenario.mode not in PBD_MODES:
        return tuple(out)
    joints_of = {}
    for j in range(m.njnt):
        joints_of.setdefault(int(m.jnt_bodyid[j]), []).append(j)
    for b, joints in joints_of.items():
        if len(joints) > 1:
            names = ", ".join(f"'{_name(m, mujoco.mjtObj.mjOBJ_JOINT, j)}'" for j in joints)
            raise ScenarioError(
                f"{mjcf}: body '{_name(m, mujoco.mjtObj.mjOBJ_BODY, b)}' has joints {names}: PBD mode steps one joint per body; "
                "nest one body per joint, or use mode \"mujoco\""
            )
    free = int(mujoco.mjtJoint.mjJNT_FREE)
    for j in range(m.njnt):
        if int(m.jnt_type[j]) != free:
            continue
        b = int(m.jnt_bodyid[j])
        body, joint = _name(m, mujoco.mjtObj.mjOBJ_BODY, b), _name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
        if int(m.body_parentid[b]) != 0:
            raise ScenarioError(f"{mjcf}: free joint '{joint}' of body '{body}' is not on a child of the world: PBD mode "
                                "cannot step it; use mode \"mujoco\"")
        welds = [e for e in range(m.neq) if int(m.eq_type[e]) == int(mujoco.mjtEq.mjEQ_WELD)
                 and b in (int(m.eq_obj1id[e]), int(m.eq_obj2id[e]))]
        held = f", held by weld '{_name(m, mujoco.mjtObj.mjOBJ_EQUALITY, welds[0])}'" if welds else ""
        out.append(
            f"{mjcf}: body '{body}' has free joint '{joint}'{held}: PBD mode then steps every body as free (no compiled "
            "joint-space path, an order of magnitude slower); " + ("delete the free joint and the weld so the body is fixed to the world"
                                                       if welds else "fix the body to the world if it does not move")
        )
    if not (m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT):
        dropped = [g for g in range(m.ngeom) if (m.geom_contype[g] or m.geom_conaffinity[g])
                   and int(m.geom_type[g]) not in PBD_CONTACT_GEOMS]
        if dropped:
            names = ", ".join(f"'{_name(m, mujoco.mjtObj.mjOBJ_GEOM, g)}' ({mujoco.mjtGeom(int(m.geom_type[g])).name.removeprefix('mjGEOM_').lower()})"
                              for g in dropped)
            out.append(
                f"{mjcf}: geom(s) {names} can collide, but PBD mode's contacts are spheres, capsules and boxes against "
                "planes: their contacts are dropped; give them contype=\"0\" conaffinity=\"0\" and add primitive collision geoms"
            )
    for e in range(m.neq):
        if int(m.eq_type[e]) not in PBD_EQUALITIES or (int(m.eq_type[e]) == int(mujoco.mjtEq.mjEQ_WELD)
                                                        and int(m.eq_objtype[e]) == int(mujoco.mjtObj.mjOBJ_SITE)):
            kind = mujoco.mjtEq(int(m.eq_type[e])).name.removeprefix("mjEQ_").lower()
            out.append(f"{mjcf}: equality '{_name(m, mujoco.mjtObj.mjOBJ_EQUALITY, e)}' ({kind}) is not enforced in PBD mode "
                       "(connect and body welds are)")
    for j in range(m.njnt):
        dof = int(m.jnt_dofadr[j])
        ignored = [what for what, value in (("frictionloss", m.dof_frictionloss[dof]), ("stiffness", m.jnt_stiffness[j])) if value]
        if ignored:
            out.append(f"{mjcf}: joint '{_name(m, mujoco.mjtObj.mjOBJ_JOINT, j)}': {' and '.join(ignored)} ignored in PBD mode")
    return tuple(out)


def disable_unbound_actuators(mjmodel: mujoco.MjModel, binding: Binding) -> None:
    """Zero force for every MJCF actuator the circuit does not drive (gain and bias 0, no dynamics), as PBD mode has it."""
    bound = set(int(i) for i in binding.actuator_id)
    for aid in range(mjmodel.nu):
        if aid in bound:
            continue
        mjmodel.actuator_dyntype[aid] = mujoco.mjtDyn.mjDYN_NONE
        mjmodel.actuator_gaintype[aid] = mujoco.mjtGain.mjGAIN_FIXED
        mjmodel.actuator_biastype[aid] = mujoco.mjtBias.mjBIAS_NONE
        mjmodel.actuator_gainprm[aid, :] = 0.0
        mjmodel.actuator_biasprm[aid, :] = 0.0


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


def build_network(scenario: Scenario, actuators=None) -> NetworkModel:
    """The scenario's circuit at its fidelity (default level + per-actuator ``[fidelity]`` overrides);
    the scenario's input schedules are range-checked against it (:func:`sim.io.scenario.check_input_ranges`).

    ``actuators`` (the MJCF's actuator names): cylinders and motors the MJCF lacks are not
    built, nor the branches that feed only them (:func:`hydraulics.network.prune`); the
    network's ``pruned`` names them first.
    """
    circuit = load_circuit(scenario.circuit)
    check_input_ranges(scenario, circuit)
    names = [c.name for c in circuit.by_kind("cylinder", "motor")]
    if not names and actuators:  # (none in the circuit and none in the MJCF: a test rig, stepped and logged as is)
        raise ScenarioError(f"{scenario.circuit}: no 'cylinder' or 'motor' component: a circuit must drive at least one "
                            f"actuator of {scenario.mjcf} (or the MJCF has no actuators: a test rig)")
    undriven = ()
    if actuators is not None and set(names) - set(actuators):
        if not set(names) & set(actuators):
            raise ScenarioError(f"{scenario.circuit}: none of its cylinders and motors {names} is an actuator of {scenario.mjcf}; "
                                f"its actuators are {sorted(actuators)}")
        circuit, undriven = prune(circuit, drives=actuators)
    for name in scenario.actuator_fidelity:
        if name not in names:
            raise ScenarioError(
                f"{scenario.path}, field 'fidelity.{name}': no cylinder or motor called '{name}' in {scenario.circuit}; "
                f"actuators: {names}"
            )
    try:
        kept = {c.name for c in circuit.components}
        network = NetworkModel.from_circuit(circuit, fidelity=scenario.fidelity,
                                            actuator_fidelity={k: v for k, v in scenario.actuator_fidelity.items() if k in kept})
        return replace(network, pruned=undriven + network.pruned) if undriven else network
    except CircuitError as exc:
        if "fidelity 'incompressible'" in str(exc):
            raise ScenarioError(f"{scenario.path}, [fidelity] / field 'run.fidelity': {str(exc).split(': ', 1)[1]}") from None
        raise


def load_scene(scenario: Scenario) -> Scene:
    """Compile the MJCF, build the network and bind them; MJCF timestep set to the scenario's dt."""
    files = mjcf_files(scenario.mjcf)
    mjmodel = load_mjmodel(scenario.mjcf, files)
    network = build_network(scenario, [mujoco.mj_id2name(mjmodel, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(mjmodel.nu)])
    notices = ()
    if network.pruned:
        dropped = set(network.pruned)
        gone = [name for name in scenario.inputs if name in dropped]
        nets = [net for net in scenario.pressures if net not in network.net_node]
        notices = (f"{scenario.circuit}: not built: {', '.join(network.pruned)} (they feed no cylinder or motor that "
                   f"{scenario.mjcf} has)" + (f"; their inputs {gone} in {scenario.path} are ignored" if gone else "")
                   + (f"; initial pressures on nets {nets} that are no longer built are ignored" if nets else ""),)
        scenario = replace(scenario, inputs={k: v for k, v in scenario.inputs.items() if k not in dropped},
                           pressures={k: v for k, v in scenario.pressures.items() if k not in nets})
    if network.fidelity == "incompressible" and scenario.fidelity != "incompressible":
        scenario = replace(scenario, fidelity="incompressible")  # every actuator overridden: the plants' switch
    elif network.fidelity != "incompressible" and scenario.fidelity == "incompressible":
        # some actuators overridden to compressible/lines: the others are rigid actuators of a compressible network
        levels = dict(zip(network.actuator_names, network.actuator_fidelity))
        scenario = replace(scenario, fidelity=network.fidelity,
                           actuator_fidelity={a: lv for a, lv in levels.items() if lv != network.fidelity})
    cylinders = {network.actuator_names[a]: float(network.cylinder_stroke[c]) for c, a in enumerate(network.cylinder_actuator)}
    mjmodel, pin_notes = pin_cylinders(mjmodel, cylinders, scenario.mjcf)
    if pin_notes:
        check_finite_model(mjmodel, scenario.mjcf)
    binding = bind(network, mjmodel, scenario.circuit, scenario.mjcf)
    warnings = notices + validate_model(mjmodel, binding, scenario)
    configure_actuators(mjmodel, binding)
    disable_unbound_actuators(mjmodel, binding)
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
    ControllerBank(scenario, network, mjmodel, scenario.dt)  # the controllers' sensors, outputs and limits exist
    scene = Scene(scenario, mjmodel, network, binding, joints, tuple(files), warnings, pin_notes)
    check_initial_joints(scene)
    check_start_pose(scene)
    return scene


JOINT_UNITS = {int(mujoco.mjtJoint.mjJNT_HINGE): "rad", int(mujoco.mjtJoint.mjJNT_SLIDE): "m"}
JOINT_RANGE_TOLERANCE = 1e-9  # rad or m: round-off allowance at a joint limit


def check_initial_joints(scene: Scene) -> None:
    """Reject ``[initial] qpos`` values on joints that are not scalar, or outside a limited joint's range."""
    m, scenario = scene.mjmodel, scene.scenario
    for key in ("qpos", "qvel"):
        for name in getattr(scenario, key):
            j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
            if int(m.jnt_type[j]) not in JOINT_UNITS:
                raise ScenarioError(
                    f"{scenario.path}, field 'initial.{key}.{name}': joint '{name}' in {scenario.mjcf} is a free or ball "
                    "joint; [initial] sets hinge and slide joints only"
                )
    for name, value in scenario.qpos.items():
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        if not m.jnt_limited[j]:
            continue
        low, high = (float(v) for v in m.jnt_range[j])
        if not (low - JOINT_RANGE_TOLERANCE <= value <= high + JOINT_RANGE_TOLERANCE):
            unit = JOINT_UNITS[int(m.jnt_type[j])]
            raise ScenarioError(
                f"{scenario.path}, field 'initial.qpos.{name}': {value!r} {unit} is outside the joint's range "
                f"[{low:g}, {high:g}] {unit} in {scenario.mjcf}"
            )


def check_start_pose(scene: Scene) -> None:
    """Reject a start pose that puts a cylinder outside its stroke, leaves a chamber with no volume, or buries a geom
    in another (:func:`check_start_penetration`).

    The extension x = tendon length − closed length (MJCF tendon range lower bound)
    must lie in [0, stroke] (± ``STROKE_TOLERANCE``), and both chamber volumes
    V_cap = V_dead,cap + A_cap·x and V_rod = V_dead,rod + A_rod·(stroke − x) [m³]
    must be positive there: otherwise the pressures are NaN at t = 0.
    """
    net, m, scenario = scene.network, scene.mjmodel, scene.scenario
    data = mujoco.MjData(m)
    data.qpos[:], data.qvel[:] = initial_qpos_qvel(scene)
    mujoco.mj_fwdPosition(m, data)
    if not len(net.cylinder_actuator):
        check_start_penetration(scene, data)
        return
    for i, a in enumerate(net.cylinder_actuator):
        name = net.actuator_names[a]
        aid, tid = scene.binding.actuator_id[a], scene.binding.tendon_id[a]
        length = float(data.ten_length[tid])
        closed = float(scene.binding.closed_length[a])
        stroke = float(net.cylinder_stroke[i])
        x = length - closed
        where = f"{scenario.path}, field 'initial.qpos'"
        if not (-STROKE_TOLERANCE <= x <= stroke + STROKE_TOLERANCE):
            raise ScenarioError(
                f"{where}: at the start pose cylinder '{name}' is {length:.4f} m pin to pin, extension x = {x:.4f} m, "
                f"outside its stroke [0, {stroke:g}] m (tendon range [{closed:g}, {closed + stroke:g}] m in {scenario.mjcf}); "
                "its chamber volumes would be wrong or negative; choose joint angles that put it inside"
            )
        xc = min(max(x, 0.0), stroke)
        cap = float(net.cylinder_dead_cap[i] + net.cylinder_cap_area[i] * xc)
        rod = float(net.cylinder_dead_rod[i] + net.cylinder_rod_area[i] * (stroke - xc))
        nodes = (net.cylinder_cap_node[i], net.cylinder_rod_node[i])
        for chamber, volume, field_name, node in (("cap", cap, "dead_volume_cap", nodes[0]), ("rod", rod, "dead_volume_rod", nodes[1])):
            if net.node_fixed[node]:
                continue  # a chamber on a tank net holds no pressure state
            if not volume + net.node_volume[node] > 0.0:
                raise ScenarioError(
                    f"{where}: at the start pose cylinder '{name}' (x = {x:.4g} m of stroke {stroke:g} m) has a {chamber} chamber "
                    f"volume of {volume:g} m^3; it must be > 0 m^3 (start away from the end of the stroke, or give "
                    f"field '{field_name}' in {scenario.circuit} a value > 0)"
                )
    check_start_penetration(scene, data)


START_PENETRATION = 0.05
"""Deepest overlap [m] of two colliding geoms the start pose may have: a shallow one is a resting contact (a tooth
pressed a centimetre into the ground, named in a warning), a deeper one a pose inside the ground or another body,
whose contact forces (megaNewtons) would throw the machine on the first step."""


def check_start_penetration(scene: Scene, data) -> None:
    """Reject a start pose in which two colliding geoms overlap by more than :data:`START_PENETRATION` (``data``: the
    start pose after ``mj_fwdPosition``, its contacts found)."""
    m, scenario = scene.mjmodel, scene.scenario
    deepest = min(range(data.ncon), key=lambda i: data.contact.dist[i], default=None)
    if deepest is None or -float(data.contact.dist[deepest]) <= START_PENETRATION:
        return
    names = [_name(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in data.contact.geom[deepest]]
    raise ScenarioError(
        f"{scenario.path}, field 'initial.qpos': at the start pose geoms '{names[0]}' and '{names[1]}' overlap by "
        f"{-float(data.contact.dist[deepest]):.3g} m (at most {START_PENETRATION:g} m: a start inside the ground or "
        "another body); choose joint angles that keep them apart")


def initial_qpos_qvel(scene: Scene, *, project: bool = True):
    """qpos, qvel arrays from the model defaults and the scenario's [initial] joint values.

    With ``project`` (default) a pose that violates the MJCF's equality
    constraints (loop closures) is moved onto them by the joints the scenario
    does not set, and qvel onto their tangent space
    (:func:`sim.plants.constraints.project_pose`); a pose they cannot close is
    refused naming the equality.
    """
    m = scene.mjmodel
    qpos = m.qpos0.copy()
    qvel = np.zeros(m.nv)
    for name, value in scene.scenario.qpos.items():
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        qpos[m.jnt_qposadr[j]] = value
    for name, value in scene.scenario.qvel.items():
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        qvel[m.jnt_dofadr[j]] = value
    if project and m.neq:
        from sim.plants.constraints import held_dofs, project_pose

        held = held_dofs(m, list(scene.scenario.qpos) + list(scene.scenario.qvel))
        qpos, qvel, _ = project_pose(m, qpos, qvel, held, where=f"{scene.scenario.path}, [initial]: ")
    return qpos, qvel
