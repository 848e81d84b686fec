"""Full-state snapshots of a plant: what a run needs to continue from a logged moment bit for bit.

:func:`capture` copies everything the next step of a block-stepping plant reads (at a block boundary, where the
plant's Python-side state is coherent, see :class:`sim.plants.mujoco_fast.MujocoPlantFast`), :func:`restore` puts
it into a freshly built plant of the same scenario, and :func:`encode` / :func:`decode` carry it through a JSON log
message with every float64 array as base64 of its raw little-endian bytes (an exact round trip, NaN included).

What is kept
------------
* the step index and the energy ledger (pump and motor work, the three dissipations, the initial total);
* the network state: node oil [m³], node pressures [Pa], valve spools [-], actuator positions [m | rad] and
  velocities, its time [s] and the last step's oil change (the implicit couplings' warm start; absent at t = 0);
* the applied efforts [N | N·m], the coupling's θ per actuator, the controls (valve commands, pump speeds);
* the last step's report (Newton counters, residual [Pa], branch flows [m³/s]: logged with every sample);
* the running extremes of node pressures and actuator coordinates (the run's peaks and its monitor);
* the PID controllers' states (held output, error, integrator, derivative term, last measurement and setpoint,
  ``hydraulics.controllers.STATE_COLUMNS``): a resumed loop samples on as the uninterrupted one;
* MuJoCo mode: ``mj_getState(..., mjSTATE_INTEGRATION)`` (time, qpos, qvel, act, warm-start accelerations,
  controls, applied forces, equality and mocap state, user data, plugin state);
* PBD mode: ``PbdPlant.snapshot()`` (rigid-group positions, orientations, linear and angular velocities, the
  hinge-unwrapping hint, the body clock, the actuator motion and row lengths, the mechanical-energy baseline and
  the compiled-step counter).

Everything else a step reads is recomputed from these at the step's start (MuJoCo's derived quantities,
the XPBD articulated data and contact rows, the network's per-step counters), which
``tests/test_play.py`` checks by resuming runs and comparing every later log message for equality.

Example
-------
>>> # state = capture(plant); message = encode(state) ... restore(other_plant, decode(message))
"""

from __future__ import annotations

import base64

import mujoco
import numpy as np

from hydraulics.network import NetworkState
from hydraulics.steppers import StepReport, StepStatus

FORMAT = 1  # snapshot message layout version
SNAPSHOT_TOPIC = "/hydroplant/snapshots"
_LEDGER = ("pump_work", "motor_work", "dissipated_hydraulic", "dissipated_friction", "dissipated_mechanical",
           "initial_total")
_EXTREMES = ("node_pressure_max", "node_pressure_min", "actuator_position_max", "actuator_position_min")
_PBD_BODY = ("x", "q", "v", "w", "qpos_hint", "body_time", "act_x", "act_v", "ell", "mechanical", "frame_steps")
_MJ_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION


def _kind(plant) -> str:
    if callable(getattr(plant, "snapshot", None)) and callable(getattr(plant, "restore", None)):
        return "pbd"
    if hasattr(plant, "data") and hasattr(plant, "model"):
        return "mujoco"
    raise TypeError(f"{type(plant).__name__}: no snapshot for this plant")


def capture(plant) -> dict:
    """The plant's full state as ``{name: float64 array | int | float | str}`` (copies)."""
    kind = _kind(plant)
    s = plant.net_state
    out = {"format": FORMAT, "kind": kind, "step_index": int(plant.step_index),
           "node_oil": s.node_oil, "node_pressure": s.node_pressure, "valve_spool": s.valve_spool,
           "actuator_position": s.actuator_position, "actuator_velocity": s.actuator_velocity,
           "net_time": float(s.time), "effort": plant.effort, "theta": plant.theta,
           "valve_command": plant.control.valve_command, "pump_speed": plant.control.pump_speed}
    if s.node_oil_change is not None:
        out["node_oil_change"] = s.node_oil_change
    if getattr(plant, "controllers", None) is not None and len(plant.controllers):
        out["controller_state"] = plant.controller_state
    e = plant.energy
    out["ledger"] = np.array([getattr(e, name) for name in _LEDGER])
    for name in _EXTREMES:
        if hasattr(plant, name):
            out[name] = getattr(plant, name)
    report = plant.last_report
    if report is not None:
        out["report"] = np.array([report.newton_iterations, report.rhs_evaluations, report.jacobian_evaluations,
                                  report.residual], float)
        out["report_status"] = report.status.value
        out["report_message"] = report.message
        out["branch_flow"] = report.branch_flow
    if kind == "mujoco":
        buffer = np.empty(mujoco.mj_stateSize(plant.model, _MJ_SPEC))
        mujoco.mj_getState(plant.model, plant.data, buffer, _MJ_SPEC)
        out["mj_state"] = buffer
    else:
        for name, value in zip(_PBD_BODY, plant.snapshot()):
            out[f"pbd_{name}"] = value
    return {k: (np.array(v, float) if isinstance(v, np.ndarray) else v) for k, v in out.items()}


def restore(plant, state: dict) -> None:
    """Put a :func:`capture` of the same scenario's plant into ``plant`` (built afresh or run on)."""
    kind = _kind(plant)
    if state.get("kind") != kind or state.get("format") != FORMAT:
        raise ValueError(f"a {state.get('kind')!r} snapshot (format {state.get('format')}) does not fit a {kind} plant "
                         f"(format {FORMAT})")
    net = plant.network
    if len(state["node_pressure"]) != net.node_count or len(state["actuator_position"]) != net.actuator_count:
        raise ValueError("the snapshot's network does not match the plant's (another circuit)")
    f = lambda name: np.array(state[name], float)  # noqa: E731 - a fresh copy per field
    plant.net_state = NetworkState(f("node_oil"), f("node_pressure"), f("valve_spool"), f("actuator_position"),
                                   f("actuator_velocity"), float(state["net_time"]),
                                   f("node_oil_change") if "node_oil_change" in state else None)
    plant.effort, plant.theta = f("effort"), f("theta")
    plant.control.valve_command[:] = state["valve_command"]
    plant.control.pump_speed[:] = state["pump_speed"]
    for name, value in zip(_LEDGER, state["ledger"]):
        setattr(plant.energy, name, float(value))
    for name in _EXTREMES:
        if name in state:
            setattr(plant, name, f(name))
    if "controller_state" in state:  # in place: the compiled blocks hold the array
        if plant.controller_state.shape != np.shape(state["controller_state"]):
            raise ValueError("the snapshot's controllers do not match the plant's (another scenario)")
        plant.controller_state[:] = state["controller_state"]
    if "report" in state:
        newton, rhs, jac, residual = state["report"]
        plant.last_report = StepReport(status=StepStatus(state["report_status"]), message=state["report_message"],
                                       newton_iterations=int(newton), rhs_evaluations=int(rhs),
                                       jacobian_evaluations=int(jac), residual=float(residual),
                                       branch_flow=f("branch_flow"))
    else:
        plant.last_report = None
    plant.step_index = int(state["step_index"])
    if kind == "mujoco":
        if len(state["mj_state"]) != mujoco.mj_stateSize(plant.model, _MJ_SPEC):
            raise ValueError("the snapshot's MuJoCo state does not match the plant's model")
        mujoco.mj_setState(plant.model, plant.data, f("mj_state"), _MJ_SPEC)
        mujoco.mj_forward(plant.model, plant.data)  # derived quantities (poses, energy) for the first sample
    else:
        body = [state[f"pbd_{name}"] for name in _PBD_BODY]
        body = [np.array(v, float) if isinstance(v, np.ndarray) else v for v in body]
        x, q, v, w, hint, body_time, act_x, act_v, ell, mechanical, frame_steps = body
        plant.restore((x, q, v, w, hint, float(body_time), act_x, act_v, ell, float(mechanical), int(frame_steps)))


def encode(state: dict) -> dict:
    """A JSON-able message of a :func:`capture`: arrays as ``{"f8": base64 of the raw float64 bytes, "shape"}``."""
    out = {}
    for name, value in state.items():
        if isinstance(value, np.ndarray):
            raw = np.ascontiguousarray(value, "<f8")
            out[name] = {"f8": base64.b64encode(raw.tobytes()).decode("ascii"), "shape": list(raw.shape)}
        elif isinstance(value, float):
            out[name] = {"f8": base64.b64encode(np.array([value], "<f8").tobytes()).decode("ascii"), "shape": []}
        else:
            out[name] = value
    return out


def decode(message: dict) -> dict:
    """The state :func:`encode` wrote (floats exact)."""
    out = {}
    for name, value in message.items():
        if name == "timestamp":
            continue
        if isinstance(value, dict) and "f8" in value:
            array = np.frombuffer(base64.b64decode(value["f8"]), "<f8").astype(float)
            out[name] = float(array[0]) if value["shape"] == [] else array.reshape(value["shape"])
        else:
            out[name] = value
    return out


__all__ = ["SNAPSHOT_TOPIC", "capture", "decode", "encode", "restore"]
