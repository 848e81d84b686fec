"""Cylinders modelled the way outside MJCFs model them: an actuator on the rod's slide joint (joint transmission)
or on a ``<fixed>`` tendon over that joint, driven instead pin to pin on the links.

A hydraulic cylinder is a two-force member: its force acts along the line from the barrel pin A to the rod eye E.
Outside models (and MuJoCo's own examples) give the barrel a body on a hinge at A, the rod a body on a slide joint
inside the barrel, and close the loop with a ``connect`` equality at the rod eye; the cylinder is an actuator on the
slide joint.  That is mechanically the cylinder's pin-to-pin line (the slide axis passes through A and E), but the
force then travels through the closing equality, which MuJoCo keeps soft: under a boom's load a light rod body
lets the closure open by millimetres to centimetres, and the machine sags while every pressure looks plausible.

:func:`pin_cylinders` rewrites such a cylinder, in the compiled model only (the user's MJCF is not touched), as a
two-site ``<spatial>`` tendon from A to E:

* A is the barrel's hinge anchor, on the barrel's parent body (the link or base the barrel is pinned to); a barrel
  without a hinge of its own keeps A on the barrel body, at the slide joint's anchor.
* E is the rod eye, on the body the rod's ``connect`` equality closes onto, at that equality's anchor; a rod that
  no equality closes keeps E on the rod body (a free slide, e.g. a test rig).

The force then acts on the links directly, exactly where the pins are, and the closure carries only the barrel's
and rod's own weight and inertia.  That is right where the links are what the cylinder moves (an arm, a boom); where
a pin's link is itself light and held by another soft closure (the side link of an H-link), the oil column would ring
that link instead.  So the pins go where the cylinder sees the most inertia counting its joints but not its closures
(:func:`inertia_seen`): on the links, or on the barrel and rod bodies as the joint transmission had them; the note
names the choice and both masses.  The tendon's length is ℓ = ℓ₀ + s·(q − q₀) along the slide (s = ±1, the sense of
the joint axis from A to E, q₀ the joint's reference position), so its range is the slide joint's range mapped the
same way: the joint's range is the stroke.  Requirements, each refused in one line naming the MJCF element: the
joint is a slide with a range, A and E lie on the slide axis within :data:`AXIS_TOLERANCE`, a fixed tendon has one
joint with coefficient ±1.  The original joint's limit still acts as the end stop; the actuator's gain, bias and
gear are replaced as for every cylinder (:func:`sim.io.scene.configure_actuators`).

Example
-------
>>> import mujoco
>>> xml = '''<mujoco><worldbody>
...   <body name="arm"><joint name="hinge" type="hinge" axis="0 1 0"/><geom size=".1" mass="1"/></body>
...   <body name="barrel" pos="0.5 0 -0.5"><joint name="pin" type="hinge" axis="0 1 0"/><geom size=".05" mass="1"/>
...     <body name="rod"><joint name="slide" type="slide" axis="0 0 1" range="0 0.3" limited="true"/>
...       <geom size=".05" mass="1"/></body></body></worldbody>
...   <equality><connect body1="rod" body2="arm" anchor="0 0 0.5"/></equality>
...   <actuator><general name="cyl" joint="slide"/></actuator></mujoco>'''
>>> model, notes = pin_cylinders(mujoco.MjModel.from_xml_string(xml), {"cyl": 0.3}, "m.xml", mujoco.MjSpec.from_string(xml))
>>> [round(float(v), 6) for v in model.tendon_range[0]]
[0.5, 0.8]
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from sim.io.scenario import ScenarioError

STROKE_TOLERANCE = 1e-3
"""Largest difference [m] between a slide joint's range width and its cylinder's stroke (as for a tendon's range)."""
AXIS_TOLERANCE = 1e-3
"""Largest distance [m] of the barrel pin and the rod eye from the slide axis; beyond it the joint's line is not the
pin-to-pin line and the model is refused."""

_SLIDE, _HINGE = int(mujoco.mjtJoint.mjJNT_SLIDE), int(mujoco.mjtJoint.mjJNT_HINGE)
_CONNECT = int(mujoco.mjtEq.mjEQ_CONNECT)


def slide_of(model: mujoco.MjModel, aid: int, name: str, mjcf) -> int | None:
    """The slide joint a cylinder actuator drives through a joint transmission or a one-joint ``<fixed>`` tendon, or
    None for any other transmission (left to :func:`sim.io.scene.check_cylinder_transmission`)."""
    trn, target = int(model.actuator_trntype[aid]), int(model.actuator_trnid[aid, 0])
    if trn == int(mujoco.mjtTrn.mjTRN_JOINT):
        joint = target
    elif trn == int(mujoco.mjtTrn.mjTRN_TENDON):
        adr, num = int(model.tendon_adr[target]), int(model.tendon_num[target])
        if not all(int(w) == int(mujoco.mjtWrap.mjWRAP_JOINT) for w in model.wrap_type[adr:adr + num]):
            return None
        tendon = _name(model, mujoco.mjtObj.mjOBJ_TENDON, target)
        if num != 1 or abs(abs(float(model.wrap_prm[adr])) - 1.0) > 1e-12:
            raise ScenarioError(f"{mjcf}: actuator '{name}' (a cylinder) acts on <fixed> tendon '{tendon}': a cylinder's "
                                "fixed tendon must hold exactly one slide joint with coef 1 or -1")
        joint = int(model.wrap_objid[adr])
    else:
        return None
    jname = _name(model, mujoco.mjtObj.mjOBJ_JOINT, joint)
    if int(model.jnt_type[joint]) != _SLIDE:
        raise ScenarioError(f"{mjcf}: actuator '{name}' (a cylinder) acts on joint '{jname}', which is not a slide; "
                            "drive the rod's slide joint, or give the cylinder a <spatial> tendon from pin to pin")
    if not model.jnt_limited[joint] or not model.jnt_range[joint, 1] > model.jnt_range[joint, 0]:
        raise ScenarioError(f"{mjcf}: joint '{jname}' (the slide of cylinder '{name}'): needs limited=\"true\" and a "
                            "range [m] whose width is the cylinder's stroke")
    return joint


def pin_cylinders(model: mujoco.MjModel, cylinders, mjcf, spec: mujoco.MjSpec | None = None) -> tuple[mujoco.MjModel, tuple]:
    """``model`` (compiled from the MJCF file ``mjcf``) with every cylinder of ``cylinders`` (actuator name → stroke
    [m] from the circuit) that drives a slide joint re-driven pin to pin (module docstring), and one note per cylinder
    rewritten.  The slide's range must be the stroke, within :data:`STROKE_TOLERANCE`.  The MJCF is
    read again as an editable :class:`mujoco.MjSpec` (or ``spec`` is edited) and compiled only when a cylinder needs
    it; otherwise ``model`` itself is returned."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)  # the reference pose qpos0: positions and the mass matrix
    notes, edits = [], []
    for name, stroke in cylinders.items():
        aid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)
        joint = slide_of(model, aid, name, mjcf) if aid >= 0 else None
        if joint is not None:
            low, high = (float(v) for v in model.jnt_range[joint])
            if abs((high - low) - stroke) > STROKE_TOLERANCE:
                raise ScenarioError(f"{mjcf}: joint '{_name(model, mujoco.mjtObj.mjOBJ_JOINT, joint)}' (the slide of cylinder "
                                    f"'{name}') has range [{low:g}, {high:g}] (width {high - low:.4f} m) but the circuit's "
                                    f"stroke is {stroke:g} m; they must agree within {STROKE_TOLERANCE} m")
            edit = _pins(model, data, name, joint, mjcf)
            edits.append(edit)
            notes.append(edit["note"])
    if not edits:
        return model, ()
    spec = mujoco.MjSpec.from_file(str(mjcf)) if spec is None else spec
    for edit in edits:
        sites = []
        for body, pos, role in (edit["barrel"], edit["eye"]):
            if body and not mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, body):
                raise ScenarioError(f"{mjcf}: cylinder '{edit['name']}': the body that holds its {role.replace('_', ' ')} "
                                    f"(body #{body}) has no name; name it so the pin can be placed on it")
            host = spec.worldbody if body == 0 else spec.body(_name(model, mujoco.mjtObj.mjOBJ_BODY, body))
            site = host.add_site()
            site.name = _unique(model, mujoco.mjtObj.mjOBJ_SITE, f"{edit['name']}_{role}")
            site.pos = pos
            sites.append(site.name)
        tendon = spec.add_tendon()
        tendon.name = _unique(model, mujoco.mjtObj.mjOBJ_TENDON, f"{edit['name']}_pins")
        tendon.wrap_site(sites[0])
        tendon.wrap_site(sites[1])
        tendon.limited = mujoco.mjtLimited.mjLIMITED_FALSE  # the slide joint's own limit is the end stop
        tendon.range = edit["range"]
        actuator = spec.actuator(edit["name"])
        actuator.trntype = mujoco.mjtTrn.mjTRN_TENDON
        actuator.target = tendon.name
        actuator.gear = [1.0, 0, 0, 0, 0, 0]
    try:
        return spec.compile(), tuple(notes)
    except Exception as exc:  # noqa: BLE001 - MuJoCo's compiler errors are ValueErrors with its message
        raise ScenarioError(f"{mjcf}: MuJoCo cannot compile the model with its cylinders driven pin to pin: "
                            f"{' '.join(str(exc).split())}") from None


def _pins(model, data, name, joint, mjcf) -> dict:
    """Barrel pin and rod eye of the cylinder ``name`` on slide ``joint``: their host bodies and local positions, the
    tendon range and a note (see :func:`pin_cylinders`)."""
    rod = int(model.jnt_bodyid[joint])
    barrel = int(model.body_parentid[rod])
    axis, anchor = data.xaxis[joint].copy(), data.xanchor[joint].copy()
    jname = _name(model, mujoco.mjtObj.mjOBJ_JOINT, joint)
    hinges = [j for j in range(model.njnt) if int(model.jnt_bodyid[j]) == barrel]
    if len(hinges) == 1 and int(model.jnt_type[hinges[0]]) == _HINGE:
        pin = data.xanchor[hinges[0]].copy()
        barrel_host, barrel_text = int(model.body_parentid[barrel]), f"hinge '{_name(model, mujoco.mjtObj.mjOBJ_JOINT, hinges[0])}'"
    else:
        pin, barrel_host, barrel_text = anchor, barrel, f"the anchor of '{jname}'"
    closures = [e for e in range(model.neq) if int(model.eq_type[e]) == _CONNECT and rod in _eq_bodies(model, e)]
    if len(closures) > 1:
        raise ScenarioError(f"{mjcf}: body '{_name(model, mujoco.mjtObj.mjOBJ_BODY, rod)}' (the rod of cylinder '{name}') "
                            f"is closed by {len(closures)} connect equalities; a rod has one eye")
    if closures:
        e = closures[0]
        bodies = _eq_bodies(model, e)
        side = 0 if bodies[0] == rod else 1
        eye_on_rod = _world(data, rod, _eq_anchor(model, e, side))
        eye_host, eye_local = bodies[1 - side], _eq_anchor(model, e, 1 - side)
        eye_text = f"connect '{_name(model, mujoco.mjtObj.mjOBJ_EQUALITY, e)}'"
    else:
        eye_on_rod = anchor + axis * (1.0 + float(model.jnt_range[joint, 1] - model.jnt_range[joint, 0]))
        eye_host, eye_local, eye_text = rod, _local(data, rod, eye_on_rod), "the rod body (no connect closes it)"
    for point, what in ((pin, f"barrel pin ({barrel_text})"), (eye_on_rod, f"rod eye ({eye_text})")):
        off = point - anchor
        distance = float(np.linalg.norm(off - axis * (off @ axis)))
        if distance > AXIS_TOLERANCE:
            raise ScenarioError(f"{mjcf}: cylinder '{name}': its {what} lies {distance * 1e3:.3g} mm off the axis of slide "
                                f"'{jname}' (at most {AXIS_TOLERANCE * 1e3:g} mm): the slide is not the pin-to-pin line; "
                                "align them, or give the cylinder a <spatial> tendon from pin to pin")
    reach = eye_on_rod - pin
    length, sense = float(np.linalg.norm(reach)), float(np.sign(reach @ axis) or 1.0)
    q0 = float(model.qpos0[model.jnt_qposadr[joint]])
    ends = sorted(length + sense * (float(q) - q0) for q in model.jnt_range[joint])
    if ends[0] <= 0.0:
        raise ScenarioError(f"{mjcf}: cylinder '{name}': its pins would meet within the range of slide '{jname}' "
                            f"(pin-to-pin {ends[0]:.4g} m at one end); check the joint's range and axis")
    body = lambda b: _name(model, mujoco.mjtObj.mjOBJ_BODY, b)  # noqa: E731
    on_links = ((barrel_host, pin), (eye_host, _world(data, eye_host, eye_local)))
    on_cylinder = ((barrel, pin), (rod, eye_on_rod))
    seen = [inertia_seen(model, data, pins, reach / length) for pins in (on_links, on_cylinder)]
    (a, pa), (b, pb) = on_links if seen[0] >= seen[1] else on_cylinder
    note = (f"{mjcf}: cylinder '{name}' on slide '{jname}' is driven pin to pin, from its barrel pin on body "
            f"'{body(a)}' ({barrel_text}) to its rod eye on body '{body(b)}' ({eye_text}), where it sees the most "
            f"inertia without its closures ({max(seen):.4g} kg; {min(seen):.4g} kg on the "
            f"{'barrel and rod bodies' if seen[0] >= seen[1] else 'links'}); pin to pin {ends[0]:.4f} to {ends[1]:.4f} m "
            "over the slide's range")
    return {"name": name, "range": ends, "note": note,
            "barrel": (a, _local(data, a, pa), "barrel_pin"), "eye": (b, _local(data, b, pb), "rod_eye")}


def inertia_seen(model, data, pins, direction) -> float:
    """Mass [kg] a force along ``direction`` between two points ``pins`` ((body, world point [m]) each) accelerates,
    counting the joints but no equality: 1/(J·M⁻¹·Jᵀ) with J = direction·(J_eye − J_barrel) at ``data``'s pose.

    Where the pins go decides which bodies ring on the oil column between the soft closures: a light body there
    (a link held by another closure, a light rod on its slide) rings at ω = √(k/m) and makes the step unstable."""
    jac = []
    for body, point in pins:
        jacp = np.zeros((3, model.nv))
        mujoco.mj_jac(model, data, jacp, None, np.asarray(point, float), int(body))
        jac.append(jacp)
    row = (np.asarray(direction, float) @ (jac[1] - jac[0])).reshape(1, model.nv)
    solved = np.zeros_like(row)
    mujoco.mj_solveM(model, data, solved, row)
    mobility = float((row @ solved.T)[0, 0])
    return 1.0 / mobility if mobility > 0.0 else math.inf


def _eq_bodies(model, e) -> tuple:
    """The two bodies of equality ``e`` (through their sites for a site-defined connect)."""
    a, b = int(model.eq_obj1id[e]), int(model.eq_obj2id[e])
    if int(model.eq_objtype[e]) == int(mujoco.mjtObj.mjOBJ_SITE):
        return int(model.site_bodyid[a]), int(model.site_bodyid[b])
    return a, b


def _eq_anchor(model, e, side) -> np.ndarray:
    """Anchor of connect ``e`` in the frame of its body ``side`` (0: first, 1: second) [m]."""
    if int(model.eq_objtype[e]) == int(mujoco.mjtObj.mjOBJ_SITE):
        return model.site_pos[int(model.eq_obj1id[e] if side == 0 else model.eq_obj2id[e])].copy()
    return model.eq_data[e, 3 * side:3 * side + 3].copy()


def _world(data, body, local) -> np.ndarray:
    return data.xpos[body] + data.xmat[body].reshape(3, 3) @ local


def _local(data, body, world) -> np.ndarray:
    return data.xmat[body].reshape(3, 3).T @ (world - data.xpos[body])


def _name(model, objtype, i) -> str:
    return mujoco.mj_id2name(model, objtype, int(i)) or ("world" if objtype == mujoco.mjtObj.mjOBJ_BODY and i == 0 else f"#{int(i)}")


def _unique(model, objtype, base) -> str:
    name, k = base, 1
    while mujoco.mj_name2id(model, objtype, name) >= 0:
        k += 1
        name = f"{base}{k}"
    return name
