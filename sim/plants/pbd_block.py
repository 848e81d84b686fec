"""Many PBD frames (plant steps) in one compiled call: :meth:`sim.plants.pbd.PbdPlant.advance`'s block path.

Per frame, in the order of the Python hooks (``tests/reference/pbd_hooks.py``: ``articulated`` → the substeps →
the end of the step):

1. the articulated data at the frame's pose (``pbd_frame._articulated_into``, on work arrays made once per block)
   where the joints form a tree of hinges and slides (``BlockPlant.joint_space``) and the mass matrix is regular;
   otherwise the frame runs without it (plain XPBD's free-body response);
2. the rigid-group state (``compiled.gather``) and the frame's contact candidates
   (``compiled.contact_candidates``), their rows copied from the per-contact arrays
   (``SolverXPBD._contact_arrays``, as ``SolverXPBD._flat_contacts``);
3. the network's per-step counters reset (``NetworkBuffers.load``), then all substeps
   (``pbd_frame._frame``, the body rows written in place, operator inputs sampled for every
   substep of the block beforehand: rows ``k·substeps .. (k+1)·substeps − 1`` of ``cmd``/``speed``);
4. the network time (+ h per successful substep), body time (+ dt), the hinge-unwrapping hint
   (``compiled.qpos_qvel`` with the previous hint), the mechanical ledger (work of the efforts minus
   Δ(kinetic + potential), ``compiled.energies``) and the running extremes of the node pressures
   (``pmax``/``pmin`` [Pa]) and actuator coordinates (``xmax``/``xmin`` [m | rad]).

The block stops after a frame whose hydraulic step failed (as ``advance`` stops at the first failed step).
Blocks of many steps equal blocks of one and the Python hooks to round-off (``tests/test_pbd_block.py``,
``tests/test_pbd_fast.py``).

Recording (as ``MujocoPlantFast.advance(n, record, every)``, the ``Recording`` layout): after every step but
the block's last whose step index becomes a multiple of ``rec[REC.EVERY]`` (``rec[REC.FIRST]``: the step index at
the block's start), the next of ``rec[REC.ROWS]`` rows of ``record`` receives the raw sample the runner's recorder
would capture after that step (``_record_row``); ``rec[REC.COUNT]`` counts the rows written, ``rec[REC.BAD]``
is 1 when one of them had a non-finite pressure or joint.

``track.clock`` (float64, by :data:`CLOCK`): body time [s], network time [s], dissipated mechanical energy [J],
kinetic + potential energy [J] at the start of the block; updated in place.
Returns (frames done, status): ``BLOCK_OK`` (all frames, or stopped after a failed hydraulic
step: the plant reads the status from ``istats``) or ``BLOCK_SINGULAR`` (the coupling's linearisation was
singular).

Caching: the entry point carries the sources' sha256 (this file, ``pbd_frame.py`` and what that covers)
as a closure variable, part of numba's cache key.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit

from hydraulics import _compiled as C
from hydraulics import controllers as CT

from sim.io import record_row
from hydraulics.layout import slots
from sim.io.record_row import RECORD_ROW
from sim.xpbd import compiled as XC
from sim.plants import pbd_frame as FN
from sim.plants import pbd_hydraulics as H

BLOCK_OK, BLOCK_SINGULAR = 0, 1

# ---------------------------------------------------------------------------- named layouts

ContactCandidates = namedtuple("ContactCandidates", [
    "group", "plane", "plane_group", "local", "radius", "plane_origin", "plane_normal",  # ``compiled.contact_candidates``
    "margin",  # candidate distance margin [m]
])

BlockPlant = namedtuple("BlockPlant", [  # what stays fixed over the plant's life
    "model",  # ``compiled.GroupModel``
    "tree",  # ``compiled.BodyTree``
    "root", "from_root_quat", "from_root_pos",  # groups from their root bodies (``compiled.gather``)
    "group_mass", "group_inertia",  # [kg], [kg·m²] (``compiled.energies``)
    "candidates",  # ``ContactCandidates``
    "contacts",  # ``compiled.ContactRows`` of every contact point of the model
    "articulated",  # ``pbd_frame.ArticulatedModel``
    "joint_space",  # the joints form a tree of hinges and slides: the articulated response applies, bool
    "actuation",  # ``pbd_frame.Actuation``
    "record_qpos", "record_qvel",  # qpos / qvel addresses of the recorded scalar joints
])

BlockBuffers = namedtuple("BlockBuffers", [  # outputs and work arrays, made once per plant
    "groups",  # ``pbd_frame.RigidState`` of the rigid groups
    "contacts",  # ``compiled.ContactRows`` of the frame's candidates (room for every contact point)
    "candidate_index",  # the frame's candidates (``compiled.contact_candidates``' out)
    "articulated",  # ``pbd_frame.Articulated``
    "xb", "qb", "qpos", "qvel",  # body frames, generalized coordinates (``compiled.qpos_qvel``)
])

CLOCK = slots(("TIME", "NET_TIME", "DISSIPATED", "MECHANICAL"))
"""Entries of ``BlockTrack.clock`` (float64): body time [s], network time [s], dissipated mechanical energy [J],
kinetic + potential energy [J]."""
REC = slots(("ROWS", "EVERY", "FIRST", "COUNT", "BAD"))
"""Entries of ``Recording.rec`` (int64): rows to record, every how many steps, the block's first step index, rows
written, 1 when a written row was not finite."""

BlockTrack = namedtuple("BlockTrack", [  # running values, updated in place
    "clock",  # (len(CLOCK),) by CLOCK
    "hint",  # hinge-unwrapping hint, (nq,)
    "pressure_max", "pressure_min",  # running node-pressure extremes [Pa], (n,)
    "position_max", "position_min",  # running actuator-position extremes [m or rad], (na,)
])

Control = namedtuple("Control", [  # the PID controllers (hydraulics.controllers)
    "table",  # parameter table, (nctl, len(PID_COLUMNS))
    "state",  # their states, updated in place, (nctl, len(STATE_COLUMNS))
    "setpoint",  # setpoint of each frame of the block, (≥ nframe, nctl)
])

Recording = namedtuple("Recording", [
    "record",  # the rows to fill, (rows, width)
    "rec",  # int64 (len(REC),) by REC
])


def _block(nframe, dt, cmd, speed, hyd, bodies, actuators, track, plant, buffers, settings, recording, control,
           transport, art_contacts):
    """Up to ``nframe`` frames of ``dt`` [s] (see the module docstring): ``cmd``/``speed`` the operator inputs of
    every substep, ``hyd`` the ``pbd_hydraulics.HydraulicBuffers``, ``bodies`` the body ``pbd_frame.RigidState``,
    ``actuators`` the ``pbd_frame.ActuatorState``, ``track`` the ``BlockTrack``, ``plant`` the ``BlockPlant``,
    ``buffers`` the ``BlockBuffers``, ``settings`` the ``pbd_frame.FrameSettings``, ``recording`` the
    ``Recording``, ``control`` the ``Control`` of the PID controllers.  Returns (frames done, status)."""
    model, tree, cand, crows, amodel, actuation = (plant.model, plant.tree, plant.candidates, plant.contacts,
                                                   plant.articulated, plant.actuation)
    groups, b, art = buffers.groups, buffers.contacts, buffers.articulated
    c_out, xb, qb, qpos, qvel = buffers.candidate_index, buffers.xb, buffers.qb, buffers.qpos, buffers.qvel
    Xg, Qg, Vg, Wg = groups.x, groups.q, groups.v, groups.w
    bx, bq, bv, bw = bodies.x, bodies.q, bodies.v, bodies.w
    clock, hint, pmax, pmin = track.clock, track.hint, track.pressure_max, track.pressure_min
    xmax, xmin, pos = track.position_max, track.position_min, hyd.position
    record, rec = recording.record, recording.rec
    istats, ledger, pres = hyd.istats, hyd.ledger, hyd.pressure
    substeps = settings.substeps
    fout = actuators.out
    rows, every, first_step = rec[REC.ROWS], rec[REC.EVERY], rec[REC.FIRST]
    rec[REC.COUNT] = 0
    rec[REC.BAD] = 0
    # the frames' work arrays, made once for the block (room for every contact candidate)
    jt = model.jt
    work = FN._frame_work_jit(actuation.cyl.size, actuators.x.size, Xg.shape[0], jt.shape[0], art.mobility.shape,
                              model.jlim.shape[0] - jt.shape[0], b.group.shape[0])
    awork = FN._articulated_work_jit(bx.shape[0], amodel.jnt_body.shape[0], art.effective_mass.size,
                                     amodel.group_mass.size)
    for k in range(nframe):
        joint_space = plant.joint_space and FN._articulated_into_jit(C.borrowed(awork), bx, bq, amodel, art)
        if not joint_space:  # plain XPBD this frame (PbdPlant.articulated: no joint-space data)
            art.motor_inverse_inertia[:] = 0.0
        XC.gather(bx, bq, bv, bw, plant.root, plant.from_root_quat, plant.from_root_pos, Xg, Qg, Vg, Wg)
        nc = XC.contact_candidates(Xg, Qg, Vg, Wg, cand.group, cand.plane, cand.plane_group, cand.local, cand.radius,
                                   cand.plane_origin, cand.plane_normal, cand.margin, dt, c_out)
        for i in range(nc):
            j = c_out[i]
            b.group[i, 0], b.group[i, 1] = crows.group[j, 0], crows.group[j, 1]
            b.vec[i, :, :] = crows.vec[j]
            b.radius[i], b.mu[i], b.condim[i], b.tran[i] = crows.radius[j], crows.mu[j], crows.condim[j], crows.tran[j]
            b.solref[i, :] = crows.solref[j]
            b.solimp[i, :] = crows.solimp[j]
        istats[:] = 0  # NetworkBuffers.load: the step's counters
        istats[H.I_WORST] = -1
        ledger[H.L_RESIDUAL] = 0.0
        ledger[H.L_FAIL_NORM] = 0.0
        contacts = XC.ContactRows(b.group[:nc], b.vec[:nc], b.radius[:nc], b.mu[:nc], b.solref[:nc], b.solimp[:nc],
                                  b.condim[:nc], b.tran[:nc])
        if control.table.shape[0]:  # the controllers from the frame's start state, held over its substeps
            _control_jit(control, first_step + k, dt, hyd, qpos, qvel, cmd[k * substeps:(k + 1) * substeps],
                     speed[k * substeps:(k + 1) * substeps], k)
        status = FN._frame_jit(hyd, cmd[k * substeps:(k + 1) * substeps], speed[k * substeps:(k + 1) * substeps],
                               groups, bodies, model, art, contacts, actuation, actuators, settings,
                               C.borrowed(work), (transport, art_contacts, joint_space))
        if status != FN.FRAME_OK:
            return k, BLOCK_SINGULAR
        for _ in range(int(fout[FN.OUT.SUBSTEPS_OK])):  # network time: + h per successful substep
            clock[CLOCK.NET_TIME] += settings.h
        clock[CLOCK.TIME] = clock[CLOCK.TIME] + dt
        XC.qpos_qvel(bx, bq, bv, bw, hint, tree, xb, qb, qpos, qvel)
        hint[:] = qpos
        kin, pot = XC.energies(bx, bq, bv, bw, plant.root, plant.from_root_quat, plant.from_root_pos, plant.group_mass,
                               plant.group_inertia, model.gravity)
        mechanical = 0 + kin + pot  # sum((kinetic, potential)), as the Python hooks
        clock[CLOCK.DISSIPATED] += fout[FN.OUT.WORK] - (mechanical - clock[CLOCK.MECHANICAL])
        clock[CLOCK.MECHANICAL] = mechanical
        if istats[H.I_STATUS] != H.ST_OK:
            return k + 1, BLOCK_OK
        for i in range(pres.size):
            pmax[i] = max(pmax[i], pres[i])
            pmin[i] = min(pmin[i], pres[i])
        for i in range(pos.size):
            xmax[i] = max(xmax[i], pos[i])
            xmin[i] = min(xmin[i], pos[i])
        if rec[REC.COUNT] < rows and k < nframe - 1 and (first_step + k + 1) % every == 0:
            last = (k + 1) * substeps - 1
            if not _record_row(record[rec[REC.COUNT]], hyd, qpos, qvel, plant.record_qpos, plant.record_qvel, actuators.effort,
                               cmd[last], speed[last], kin, pot, clock[CLOCK.DISSIPATED], xb, qb, control.state):
                rec[REC.BAD] = 1
            rec[REC.COUNT] += 1
    return nframe, BLOCK_OK


_record_views = njit(inline="always")(RECORD_ROW.carver(C._matrix))


def _control(control, step, dt, hyd, qpos, qvel, cmd, speed, k):
    """The PID controllers of plant step ``step`` (:func:`hydraulics.controllers.update`) from the frame's start
    state (the network's actuator motion, pressures and last flows, qpos/qvel of the previous frame's end), their
    outputs written into the first substep's row of ``cmd``/``speed`` and held over the frame's other rows."""
    sources = (hyd.position, hyd.velocity, qpos, qvel, hyd.pressure, hyd.flow)  # CT.SOURCES
    CT.update(control.table, control.state, control.setpoint[k], step, dt, sources, cmd[0], speed[0])
    for s in range(1, cmd.shape[0]):
        CT.update_outputs(control.table, control.state, cmd[s], speed[s])


@njit(cache=True)
def _record_row(row, hyd, qpos, qvel, rq, rd, effort, cmd, speed, kinetic, potential, dissipated_mechanical, xb, qb,
                controller_state):
    """One raw sample (:data:`sim.io.record_row.RECORD_ROW`, the scalar joints ``rq``/``rd`` of ``qpos``/``qvel`` as
    its joints) for a plant with ``joint_state``; returns whether the node pressures and joints are finite
    (``RunRecorder.captured_finite``).  ``hyd``: the network's ``pbd_hydraulics.HydraulicBuffers``."""
    ledger = hyd.ledger
    r, _ = _record_views(row, 0, hyd.pressure.size, rq.size, rd.size, hyd.position.size, cmd.size, hyd.spool.size,
                         speed.size, hyd.flow.size, xb.shape[0], controller_state.shape[0])
    C._copy(r.p, hyd.pressure)
    for i in range(rq.size):
        r.qpos[i] = qpos[rq[i]]
    for i in range(rd.size):
        r.qvel[i] = qvel[rd[i]]
    finite = True
    for part in (r.p, r.qpos, r.qvel):
        for x in part:
            if not np.isfinite(x):
                finite = False
    C._copy(r.oil, hyd.oil)
    C._copy(r.x, hyd.position)
    C._copy(r.v, hyd.velocity)
    C._copy(r.effort, effort)
    C._copy(r.theta, hyd.theta)
    C._copy(r.cmd, cmd)
    C._copy(r.spool, hyd.spool)
    C._copy(r.speed, speed)
    C._copy(r.flow, hyd.flow)
    r.solver[0], r.solver[1] = hyd.istats[H.I_NEWTON], ledger[H.L_RESIDUAL]
    r.energy[0], r.energy[1] = kinetic, potential
    r.energy[2], r.energy[3], r.energy[4] = ledger[H.L_PUMP], ledger[H.L_DISS_H], ledger[H.L_DISS_F]
    r.energy[5] = dissipated_mechanical
    C._copy2(r.xpos, xb)
    C._copy2(r.xquat, qb)
    C._copy2(r.controllers, controller_state)  # the controllers' states (hydraulics.controllers.STATE_COLUMNS)
    return finite


# this file and everything frame_nb compiles in, taken at import: part of the cache key
SOURCE_SHA256 = C.source_sha256(__file__, FN.__file__, H.__file__, XC.__file__, CT.__file__, record_row.__file__,
                                *C.SOURCES)


_BLOCK = {}
_block_jit = _control_jit = None


def block(transport: bool = False, articulated_contacts: bool = True):
    """The compiled block (numba's disk cache, or compiled on first use; one signature per variant).

    ``transport`` (as ``XpbdOptions(transport_response=...)``): carry the step's articulated responses to each
    substep's pose (``compiled.transport``); False keeps them as given for the whole step.
    ``articulated_contacts`` (as ``XpbdOptions(articulated_contacts=...)``): solve the contact pyramids with the
    mechanism's articulated response."""
    global _block_jit, _control_jit
    key = (bool(transport), bool(articulated_contacts))
    if key not in _BLOCK:
        import numba

        FN.compile_helpers()  # the frame's jitted functions (_frame_jit, _frame_work_jit)
        FN.articulated()  # and the articulated response's (_articulated_*_jit)
        if _block_jit is None:
            _block_jit = numba.njit(error_model="numpy")(_block)
            _control_jit = numba.njit(error_model="numpy")(_control)
        fingerprint = SOURCE_SHA256
        transport_, contacts_ = key

        def block_entry(*args):
            if fingerprint is None:  # never: only makes the fingerprint a closure variable (numba's cache key)
                return -1, -1
            # the block's arrays are owned by the caller for the whole call: its callees borrow them
            # (no atomic reference counting per call; see hydraulics._compiled.borrowed)
            return _block_jit(*C.borrowed(args), transport_, contacts_)

        _BLOCK[key] = numba.njit(cache=True, error_model="numpy")(block_entry)
    return _BLOCK[key]
