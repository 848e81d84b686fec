"""Many PBD frames (plant steps) in one compiled call: :meth:`sim.plants.pbd.PbdPlant.advance`'s block path.

Per frame, in the order of :meth:`~sim.plants.pbd.PbdPlant.step` on its compiled-frame path
(``articulated`` → ``_step_frame`` → ``_end_step``), each piece the same compiled function
the per-frame path calls from Python:

1. the articulated data at the frame's pose (``frame_nb._articulated_into``, on work arrays made once per block);
2. the rigid-group state (``compiled.gather``) and the frame's contact candidates
   (``compiled.contact_candidates``), their rows copied from the per-contact arrays
   (``SolverXPBD._contact_arrays``, as ``SolverXPBD._flat_contacts``);
3. the network's per-step counters reset (``FastHydraulics.load``), then all substeps
   (``frame_nb._frame``, the body rows written in place, operator inputs sampled for every
   substep of the block beforehand: rows ``k·substeps .. (k+1)·substeps − 1`` of ``cmd``/``speed``);
4. the network time (+ h per successful substep), body time (+ dt), the hinge-unwrapping hint
   (``compiled.qpos_qvel`` with the previous hint), the mechanical ledger (work of the efforts minus
   Δ(kinetic + potential), ``compiled.energies``) and the running extremes of the node pressures
   (``pmax``/``pmin`` [Pa]) and actuator coordinates (``xmax``/``xmin`` [m | rad]).

The block stops after a frame whose hydraulic step failed (as ``advance`` stops at the first
failed step), and before a frame the compiled frame does not cover (singular mass matrix, a
contact that is not soft and pyramidal: the plant steps that frame on its per-frame path).
Results equal the per-frame path to round-off (``tests/test_pbd_block.py``).

Recording (as ``MujocoPlantFast.advance(n, record, every)``): after every step but the block's
last whose step index becomes a multiple of ``rec[1]`` (``rec[2]``: the step index at the block's
start), the next of ``rec[0]`` rows of ``record`` receives the raw sample the runner's recorder
would capture after that step (``_record_row``); ``rec[3]`` counts the rows written, ``rec[4]``
is 1 when one of them had a non-finite pressure or joint.

``clock`` (float64, 4): body time [s], network time [s], dissipated mechanical energy [J],
kinetic + potential energy [J] at the start of the block; updated in place.
Returns (frames done, status): ``BLOCK_OK`` (all frames, or stopped after a failed hydraulic
step: the plant reads the status from ``istats``), ``BLOCK_SINGULAR`` (the coupling's
linearisation was singular), ``BLOCK_INELIGIBLE`` (stopped before a frame the compiled frame
does not cover).

Caching as :mod:`sim.plants.pbd_frame`: the entry point carries the sources' sha256 (this file,
``frame_nb.py`` and what that covers) as a closure variable.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from hydraulics import _compiled as C

from sim.xpbd import compiled as XC
from sim.plants import pbd_frame as FN
from sim.plants import pbd_hydraulics as H

BLOCK_OK, BLOCK_SINGULAR, BLOCK_INELIGIBLE = 0, 1, 2


def _block(nframe, dt, h, substeps, iterations, symmetric, cmd, speed,
           F, I, Wk, S, istats, ledger, quad, oil, pres, spool, pos, vel, flow,
           bx, bq, bv, bw, hint, clock, pmax, pmin, xmax, xmin,
           root, from_root_quat, from_root_pos, Xg, Qg, Vg, Wg,
           IM, II, GI, gravity, jt, jg, jvec, jqoff, jlim, jlo, jhi, jdamp, et, eg, evec, eqoff, rg, rvec,
           c_group, c_plane, c_plane_group, c_local, c_radius, c_origin, c_normal, margin, c_out, c_eligible,
           c_cg, c_cvec, c_crad, c_mu, c_solref, c_solimp, c_condim, c_tran,
           b_cg, b_cvec, b_crad, b_mu, b_solref, b_solimp, b_condim, b_tran,
           cone, impratio, lin_damp, ang_damp, body_group, in_group_quat, in_group_pos,
           iquat, ipos, jnt_body, jnt_axis, jnt_pos, hinge, subtree, body_mass, inertia, armature, site_body, site_pos,
           row_sites, mot_dof, group_mass, group_root, group_dynamic,
           mobility, group_gravity, motor_response, minv, effective_mass,
           group_inertia, parent, body_quat, body_pos, jnt_type, jnt_qposadr, jnt_dofadr, qpos0, xb, qb, qpos, qvel,
           cyl, closed, mot, gear, mbody, mparent, maxis, x, v, ell0, const, slope, effort, motor_effort, fout,
           record, rec, rq, rd, theta, scheme, blend, transport, art_contacts):
    rows, every, first_step = rec[0], rec[1], rec[2]
    rec[3] = 0  # rows recorded
    rec[4] = 0  # a recorded row was not finite
    # the frames' work arrays, made once for the block (room for every contact candidate)
    work = FN._frame_work_jit(cyl.size, x.size, Xg.shape[0], jt.shape[0], mobility.shape, jlim.shape[0] - jt.shape[0],
                              b_cg.shape[0])
    awork = FN._articulated_work_jit(bx.shape[0], jnt_body.shape[0], effective_mass.size, group_mass.size)
    for k in range(nframe):
        if not FN._articulated_into_jit(
                C.borrowed(awork), bx, bq, iquat, ipos, jnt_body, jnt_axis, jnt_pos, hinge, subtree, body_mass, inertia, armature, gravity,
                site_body, site_pos, row_sites, cyl, mot, mot_dof, gear, body_group, group_mass, group_root,
                group_dynamic, mobility, group_gravity, motor_response, minv, effective_mass):
            return k, BLOCK_INELIGIBLE
        XC.gather(bx, bq, bv, bw, root, from_root_quat, from_root_pos, Xg, Qg, Vg, Wg)
        nc = XC.contact_candidates(Xg, Qg, Vg, Wg, c_group, c_plane, c_plane_group, c_local, c_radius, c_origin,
                                   c_normal, margin, dt, c_out)
        for i in range(nc):
            if not c_eligible[c_out[i]]:
                return k, BLOCK_INELIGIBLE
        for i in range(nc):
            j = c_out[i]
            b_cg[i, 0], b_cg[i, 1] = c_cg[j, 0], c_cg[j, 1]
            b_cvec[i, :, :] = c_cvec[j]
            b_crad[i], b_mu[i], b_condim[i], b_tran[i] = c_crad[j], c_mu[j], c_condim[j], c_tran[j]
            b_solref[i, :] = c_solref[j]
            b_solimp[i, :] = c_solimp[j]
        istats[:] = 0  # FastHydraulics.load: the step's counters
        istats[H.I_WORST] = -1
        ledger[H.L_RESIDUAL] = 0.0
        ledger[H.L_FAIL_NORM] = 0.0
        status = FN._frame_jit(
            F, I, Wk, S, istats, ledger, quad, oil, pres, spool, pos, vel, cmd[k * substeps:(k + 1) * substeps],
            speed[k * substeps:(k + 1) * substeps], Xg, Qg, Vg, Wg, IM, II, GI, gravity, h, substeps, iterations,
            symmetric, jt, jg, jvec, jqoff, jlim, jlo, jhi, jdamp, et, eg, evec, eqoff, rg, rvec, mobility,
            group_gravity, motor_response, b_cg[:nc], b_cvec[:nc], b_crad[:nc], b_mu[:nc], b_solref[:nc],
            b_solimp[:nc], b_condim[:nc], b_tran[:nc], cone, impratio, lin_damp, ang_damp, body_group,
            in_group_quat, in_group_pos, bx, bq, bv, bw, cyl, closed, mot, gear, minv, mbody, mparent, maxis,
            x, v, ell0, const, slope, effort, motor_effort, flow, fout, scheme, blend, effective_mass, theta,
            C.borrowed(work), transport, art_contacts)
        if status != FN.FRAME_OK:
            return k, BLOCK_SINGULAR
        for _ in range(int(fout[1])):  # network time: + h per successful substep (FastHydraulics.finish)
            clock[1] += h
        clock[0] = clock[0] + dt
        XC.qpos_qvel(bx, bq, bv, bw, hint, iquat, ipos, parent, body_quat, body_pos, jnt_type, jnt_body,
                     jnt_qposadr, jnt_dofadr, jnt_axis, qpos0, xb, qb, qpos, qvel)
        hint[:] = qpos
        kin, pot = XC.energies(bx, bq, bv, bw, root, from_root_quat, from_root_pos, group_mass, group_inertia, gravity)
        mechanical = 0 + kin + pot  # sum((kinetic, potential)), as PbdPlant._end_step
        clock[2] += fout[0] - (mechanical - clock[3])
        clock[3] = mechanical
        if istats[H.I_STATUS] != H.ST_OK:
            return k + 1, BLOCK_OK
        for i in range(pres.size):
            pmax[i] = max(pmax[i], pres[i])
            pmin[i] = min(pmin[i], pres[i])
        for i in range(pos.size):
            xmax[i] = max(xmax[i], pos[i])
            xmin[i] = min(xmin[i], pos[i])
        if rec[3] < rows and k < nframe - 1 and (first_step + k + 1) % every == 0:
            last = (k + 1) * substeps - 1
            if not _record_row(record[rec[3]], pres, qpos, qvel, rq, rd, oil, pos, vel, effort, theta, cmd[last], spool,
                               speed[last], flow, istats[H.I_NEWTON], ledger[H.L_RESIDUAL], kin, pot, ledger, clock[2],
                               xb, qb):
                rec[4] = 1
            rec[3] += 1
    return nframe, BLOCK_OK


@njit(cache=True)
def _put(row, o, values):
    for i in range(values.size):
        row[o + i] = values[i]
    return o + values.size


@njit(cache=True)
def _record_row(row, pres, qpos, qvel, rq, rd, oil, pos, vel, effort, theta, cmd, spool, speed, flow, newton, residual,
                kinetic, potential, ledger, dissipated_mechanical, xb, qb):
    """One raw sample in the layout of ``RunRecorder.capture`` for a plant with ``joint_state``: node pressures [Pa],
    scalar-joint positions and rates, node oil, actuator positions, velocities, efforts, θ, valve commands, spools,
    pump speeds, branch flows, Newton iterations and residual [Pa], kinetic, potential energy, pump work, hydraulic,
    friction and mechanical dissipation [J], body-frame positions [m] and quaternions; returns whether the node
    pressures and joints are finite (``RunRecorder.captured_finite``)."""
    o = _put(row, 0, pres)
    for i in range(rq.size):
        row[o + i] = qpos[rq[i]]
    o += rq.size
    for i in range(rd.size):
        row[o + i] = qvel[rd[i]]
    o += rd.size
    finite = True
    for i in range(o):
        if not np.isfinite(row[i]):
            finite = False
    o = _put(row, o, oil)
    o = _put(row, o, pos)
    o = _put(row, o, vel)
    o = _put(row, o, effort)
    o = _put(row, o, theta)
    o = _put(row, o, cmd)
    o = _put(row, o, spool)
    o = _put(row, o, speed)
    o = _put(row, o, flow)
    row[o], row[o + 1] = newton, residual
    row[o + 2], row[o + 3] = kinetic, potential
    row[o + 4], row[o + 5], row[o + 6] = ledger[H.L_PUMP], ledger[H.L_DISS_H], ledger[H.L_DISS_F]
    row[o + 7] = dissipated_mechanical
    o += 8
    for b in range(xb.shape[0]):
        for c in range(3):
            row[o] = xb[b, c]
            o += 1
    for b in range(qb.shape[0]):
        for c in range(4):
            row[o] = qb[b, c]
            o += 1
    return finite


# this file and everything frame_nb compiles in, taken at import: part of the cache key
SOURCE_SHA256 = C.source_sha256(__file__, FN.__file__, H.__file__, XC.__file__, *C.SOURCES)


_BLOCK = {}
_block_jit = None


def block(transport: bool = False, articulated_contacts: bool = True):
    """The compiled block (numba's disk cache, or compiled on first use; one signature per variant),
    ``transport``/``articulated_contacts`` as :func:`sim.plants.pbd_frame.frame`."""
    global _block_jit
    key = (bool(transport), bool(articulated_contacts))
    if key not in _BLOCK:
        import numba

        FN.frame(*key)  # makes frame_nb's compiled helpers (_frame_jit, _frame_work_jit, _articulated_*_jit) exist
        FN.articulated()
        if _block_jit is None:
            _block_jit = numba.njit(error_model="numpy")(_block)
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
