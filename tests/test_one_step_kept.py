"""The work the ``rosenbrock`` step skips in MuJoCo mode gives the same numbers, bit for bit.

* :func:`hydraulics._compiled._trust_step` skips the nodes whose update is within half of a lower bound of the
  trust region (V_g·TRUST_PRESSURE/β at p ≥ p_ref, pure oil): its fraction equals that of every node evaluated.
* :func:`hydraulics._compiled._linearize_one_step_from` with ``known`` 2 keeps the previous step's end flows of the
  branches whose arguments did not change (an orifice at the same open area, a stateless law at the same scheduled
  inputs) and the stateless law branches' pieces: its outputs equal those of the linearisation that evaluates them.
"""

import numpy as np
import pytest

from conftest import MODELS
from hydraulics import numerics
from hydraulics._compiled import compiled_available

pytestmark = pytest.mark.skipif(not compiled_available(), reason="numba is not installed")

DT = 1e-3  # s


def _kernels():
    import numba

    from hydraulics import _compiled as C

    @numba.njit
    def trust_fractions(F, I, oil, deltas, geo, p):
        """_trust_step, and the same fraction with every free node evaluated (its formula), for each row of deltas."""
        pnet = C._ref(C._unpack(F, I))
        net = C._deref(pnet)
        sc, free = net.sc, net.free
        out = np.empty((deltas.shape[0], 2))
        for r in range(deltas.shape[0]):
            delta = deltas[r]
            out[r, 0] = C._trust_step(pnet, oil, delta, geo, p)
            smallest = np.inf
            for j in range(free.size):
                k = free[j]
                volume, beta = C._volume_and_modulus(pnet, k, geo[k], p[k])
                void = max(volume * sc[C.S_PHI_FLOOR] - oil[k], 0.0)
                allowed = void + volume * max(sc[C.S_TRUST_P], sc[C.S_TRUST_F] * abs(p[k])) / beta
                ratio = allowed / abs(delta[j]) if abs(delta[j]) > 0 else np.inf
                smallest = min(smallest, ratio)
            out[r, 1] = smallest if smallest < 1.0 else 1.0
        return out

    @numba.njit
    def pressures(F, I, oil, x):
        pnet = C._ref(C._unpack(F, I))
        n = oil.size
        geo, p, dpdm = np.empty(n), np.empty(n), np.empty(n)
        C._pressure(pnet, oil, x, geo, p, dpdm)
        return geo, p, dpdm

    @numba.njit
    def linearize(F, I, oil, spool, speed, x, v, spool_before, speed_before, kept):
        """The one-step linearisation from the known start evaluation (``known`` 1), or (``kept``) from the end flows
        at the start pressures with the areas of ``spool_before`` and the inputs ``speed_before`` (``known`` 2);
        returns its outputs and how many branches the known-2 path could keep."""
        net = C._unpack(F, I)
        pnet = C._ref(net)
        ic = net.ic
        n, nb, nf, na = ic[C.IC_N], ic[C.IC_NB], ic[C.IC_NF], ic[C.IC_NA]
        geo, p0, dpdm = np.empty(n), np.empty(n), np.empty(n)
        C._pressure(pnet, oil, x, geo, p0, dpdm)
        W = np.full(C._linearize_work_size(ic), np.nan)
        ws, _ = C._one_step_scratch(W, 0, n, na, nb, nf, C._area_count(ic), ic[C.IC_NJQ], ic[C.IC_NLU])
        flow_before, dflow_before = np.empty(nb), np.empty((nb, C._W_BR))
        if kept:  # what the step before and its finish leave: its areas and start law pieces in W, its end flows
            C._valve_areas(pnet, spool_before, ws.area)
            C._law_pieces(pnet, p0, spool_before, DT, ws.pieces)
            C._branch_flows(pnet, p0, ws.area, speed_before, v, flow_before, dflow_before, spool_before, DT)
        end_spool = np.empty(spool.size)
        C._spool_end(pnet, spool, spool, DT, end_spool)
        new_area = np.empty(C._area_count(ic))
        C._valve_areas(pnet, end_spool, new_area)
        same, orifices = 0, ic[C.IC_O1] - ic[C.IC_O0]
        for i in range(orifices):
            if kept and new_area[i] == ws.area[i]:
                same += 1
        out = C.LinearizationOut(np.empty(n), np.empty(n), np.empty(spool.size), np.empty(na), np.empty(nb),
                                 np.zeros(C.NIS, np.int64), np.empty(na), np.empty((na, na)), p0, np.empty((n, na)))
        accepted = C._linearize_one_step_from(pnet, W, C.StepStart(oil, spool, spool, speed, x, v), DT, out,
                                              2 if kept else 1, geo, dpdm, (flow_before, dflow_before, speed_before))
        return (accepted, out.oil, out.pressure, out.flow, out.effort, out.gradient, out.oil_gradient,
                ws.residual.copy(), same, orifices)

    return trust_fractions, pressures, linearize


def _dig_states(count):
    """``count`` states of the excavator dig at 1 kHz, 0.5 s apart (rosenbrock in MuJoCo mode)."""
    from sim.io.scenario import load_scenario
    from sim.io.scene import load_scene
    from sim.plants.mujoco_fast import MujocoPlantFast

    scenario = load_scenario(MODELS / "excavator" / "dig.scenario.toml").with_overrides(dt=DT)
    plant = MujocoPlantFast(load_scene(scenario), coupling="rosenbrock")
    states = []
    for _ in range(count):
        assert plant.advance(500).success
        states.append((plant._oil.copy(), plant._spool.copy(), plant._speed[499].copy(), plant._x.copy(),
                       plant._v.copy()))
    return plant, states


def test_trust_step_skipping_certain_nodes_is_exact():
    """The trust fraction of updates from 1e-9 to 10 times the skip bound and past the whole trust region, of
    either sign, at the dig's states (pure oil, wall-compliant nodes): the same fraction, bit for bit, as with
    every free node evaluated; both the skipped and the limiting cases occur."""
    trust_fractions, pressures, _ = _kernels()
    plant, states = _dig_states(6)
    net = plant.network
    free = np.asarray(net.free_nodes)
    rng = np.random.default_rng(5)
    limited = 0
    for oil, _, _, x, _ in states:
        geo, p, _ = pressures(plant._F, plant._I, oil, x)
        bound = 0.5 * numerics.TRUST_PRESSURE / net.fluid.bulk_modulus * geo[free]  # the skip bound
        scale = 10.0 ** rng.uniform(-9, 1.5, (400, free.size)) * rng.choice([-1.0, 1.0], (400, free.size))
        deltas = bound * scale
        fractions = trust_fractions(plant._F, plant._I, oil, deltas, geo, p)
        np.testing.assert_array_equal(fractions[:, 0], fractions[:, 1])
        limited += int(np.sum(fractions[:, 0] < 1.0))
    assert 100 < limited < 6 * 400  # some updates leave the trust region, others do not


def test_kept_flows_and_pieces_give_the_same_linearisation():
    """At the dig's states, the one-step linearisation that keeps the end flows of the step before (its valve
    areas: the state's spools, or one valve's spool moved; its pump speed the same or not) equals, bit for bit, the
    one that evaluates every branch at the start pressures; both kept and evaluated branches occur."""
    _, _, linearize = _kernels()
    plant, states = _dig_states(8)
    kept_any = moved_any = 0
    for oil, spool, speed, x, v in states:
        for before_spool, before_speed in ((spool, speed), (spool + np.array([0.02, 0.0, 0.0, 0.0]), speed),
                                           (spool, speed * 1.01)):
            evaluated = linearize(plant._F, plant._I, oil, spool, speed, x, v, before_spool, before_speed, False)
            kept = linearize(plant._F, plant._I, oil, spool, speed, x, v, before_spool, before_speed, True)
            assert kept[0] == evaluated[0]
            if evaluated[0]:
                for a, b in zip(kept[1:-2], evaluated[1:-2]):
                    np.testing.assert_array_equal(a, b)
            same, orifices = kept[-2:]
            kept_any += same > 0
            moved_any += same < orifices
    assert kept_any > 0 and moved_any > 0
