"""Error metrics on synthetic logs with known errors, the convergence check, and ``hydroplant compare`` on logs."""

import argparse
import math

import numpy as np
import pytest

from conftest import MODELS
from hydraulics.components import CircuitError
from sim.tools import compare
from sim.tools.compare import align, compare_logs, error_series, error_stats, log_signals, richardson_first_order
from sim.io.mcap_log import LogWriter, flat_schema, read_log
from sim.run.recorder import CYLINDER_FIELDS
from sim.tools.reference import NotConvergedError, Tolerance, check_convergence, compute_reference, require_converged

SEED = MODELS / "seed_cylinder" / "closed.scenario.toml"
OMEGA = 2 * math.pi * 2.0  # rad/s of the synthetic signals


def write_log(path, dt, duration, *, stroke, pressure=None, joint=None, scene="synthetic", status="complete",
              diverged_at=None):
    """A log with the run topics of one cylinder ``c`` and one joint ``j``: values are functions of t [s]."""
    pressure = pressure or (lambda t: 1e7 + 1e6 * np.sin(OMEGA * t))
    joint = joint or stroke
    steps = int(round(duration / dt))
    if diverged_at is not None:
        steps = int(round(diverged_at / dt))
    meta = {"scene": scene, "dt_s": repr(dt), "mode": "mujoco", "coupling": "implicit"}
    with LogWriter(path, dt=dt, run_metadata=meta, overwrite=True) as log:
        joints = log.joint_states_channel("/hydroplant/joint_states", ["j"])
        cyl = log.channel("/hydroplant/cylinders/c", "hydroplant.CylinderState", flat_schema("hydroplant.CylinderState", CYLINDER_FIELDS),
                          fields=list(CYLINDER_FIELDS))
        for n in range(steps + 1):
            t = n * dt
            joints.append(n, [joint(t)], [0.0])
            cyl.append(n, (stroke(t), 0.0, pressure(t), 1e5, 0.0, 0.0, 0.0, 1.0, pressure(t) / 1e5, 1.0))
        if diverged_at is not None:
            log.mark("diverged", time_s=repr(steps * dt), component="test", message="synthetic")
        elif status == "complete":
            log.mark("complete")
    return path


def sine(t):
    return 0.5 + 0.1 * np.sin(OMEGA * t)  # stroke [m]: range 0.2 m


# ---------------------------------------------------------------------------------------
# Pure metrics
# ---------------------------------------------------------------------------------------


def test_offset_gives_max_and_rms_equal_to_the_offset():
    t = np.arange(0, 1.0, 1e-3)
    s = error_stats(t, sine(t), t, sine(t) + 0.003)
    assert s.max_abs == pytest.approx(0.003, rel=1e-9) and s.rms == pytest.approx(0.003, rel=1e-9)
    assert s.ref_range == pytest.approx(0.2, rel=1e-4) and s.max_rel == pytest.approx(0.015, rel=1e-3)
    assert s.samples == len(t)


def test_delay_gives_the_analytic_error_of_a_shifted_sine():
    """y(t) = a·sin(ω(t − d)): |e| peaks at 2a·sin(ωd/2), its RMS over whole periods is √2·a·sin(ωd/2)."""
    t = np.arange(0, 1.0, 1e-4)  # two whole periods
    d = 0.01
    s = error_stats(t, sine(t), t, sine(t - d))
    peak = 2 * 0.1 * math.sin(OMEGA * d / 2)
    assert s.max_abs == pytest.approx(peak, rel=1e-6)
    assert s.rms == pytest.approx(peak / math.sqrt(2), rel=1e-3)


def test_different_rates_interpolate_the_denser_signal():
    """Reference at 1 kHz, run at 300 Hz (not on the reference's grid): the run's grid is used, the reference
    interpolated; an exact run shows only the interpolation error (< ω²h²/8 · amplitude), an offset run the offset."""
    t_ref = np.arange(0, 1.0 + 1e-9, 1e-3)
    t = np.arange(0, 1.0, 1 / 300)
    times, ref, other = align(t_ref, sine(t_ref), t, sine(t))
    assert np.array_equal(times, t)  # the sparser grid
    bound = 0.1 * OMEGA**2 * 1e-6 / 8
    assert error_stats(t_ref, sine(t_ref), t, sine(t)).max_abs < bound
    assert error_stats(t_ref, sine(t_ref), t, sine(t) - 0.002).max_abs == pytest.approx(0.002, abs=bound)
    # and the other way round: a sparser reference is the grid
    times, _, _ = align(t, sine(t), t_ref, sine(t_ref))
    assert np.array_equal(times, t)


def test_align_covers_only_the_common_span_and_drops_non_finite_samples():
    t = np.arange(0, 1.0, 0.01)
    y = sine(t)
    y_run = y.copy()
    y_run[50:] = np.nan  # a run that went non-finite at 0.5 s
    times, e = error_series(t, y, t[:60], y_run[:60] + 0.001)
    assert times[-1] == pytest.approx(0.49) and np.allclose(e, 0.001)
    s = error_stats(t, y, t[:0], y[:0])
    assert s.samples == 0 and math.isnan(s.max_abs)


# ---------------------------------------------------------------------------------------
# Synthetic logs
# ---------------------------------------------------------------------------------------


def test_compare_logs_with_offset_delay_and_rate(tmp_path):
    ref = write_log(tmp_path / "ref.mcap", 1e-3, 1.0, stroke=sine)
    offset = write_log(tmp_path / "offset.mcap", 1e-3, 1.0, stroke=lambda t: sine(t) + 0.004,
                       pressure=lambda t: 1e7 + 1e6 * np.sin(OMEGA * t) + 2e5)
    delayed = write_log(tmp_path / "delay.mcap", 1e-3, 1.0, stroke=lambda t: sine(t - 0.005))
    coarse = write_log(tmp_path / "coarse.mcap", 1 / 300, 1.0, stroke=sine)
    c = compare_logs(ref, offset)
    assert c.signals["stroke c"].max_abs == pytest.approx(0.004, rel=1e-9)
    assert c.signals["joint j"].rms == pytest.approx(0.004, rel=1e-9)
    assert c.signals["p_cap c"].max_abs == pytest.approx(2e5, rel=1e-9)
    assert c.signals["p_rod c"].max_abs == 0.0
    assert c.kind_stats("pressure")["worst"] == "p_cap c"
    assert c.status == "complete" and c.stable
    d = compare_logs(ref, delayed)
    assert d.signals["stroke c"].max_abs == pytest.approx(2 * 0.1 * math.sin(OMEGA * 0.005 / 2), rel=1e-3)
    r = compare_logs(ref, coarse)
    assert r.signals["stroke c"].samples == 301 and r.signals["stroke c"].max_abs < 1e-5


def test_diverged_log_is_compared_until_it_stopped(tmp_path):
    ref = write_log(tmp_path / "ref.mcap", 1e-3, 1.0, stroke=sine)
    run = write_log(tmp_path / "div.mcap", 1e-3, 1.0, stroke=lambda t: sine(t) + 0.001, diverged_at=0.4)
    c = compare_logs(ref, run)
    assert c.status == "diverged" and c.diverged_at == pytest.approx(0.4)
    assert c.signals["stroke c"].t_end == pytest.approx(0.4)
    assert "diverged at 0.4 s" in compare.summary_table([c])


def test_logs_of_different_scenes_are_refused(tmp_path):
    ref = write_log(tmp_path / "ref.mcap", 1e-3, 0.1, stroke=sine, scene="boom")
    other = write_log(tmp_path / "other.mcap", 1e-3, 0.1, stroke=sine, scene="excavator")
    with pytest.raises(CircuitError, match="different scenes.*'boom' vs 'excavator'"):
        compare_logs(ref, other)


def _cli(argv):
    parser = argparse.ArgumentParser()
    compare.add_parser(parser.add_subparsers())
    args = parser.parse_args(argv)
    return args.func(args)


def test_cli_compare_two_logs_writes_report_figures_and_merged_log(tmp_path, capsys):
    ref = write_log(tmp_path / "ref.mcap", 1e-3, 0.5, stroke=sine)
    run = write_log(tmp_path / "run.mcap", 2e-3, 0.5, stroke=lambda t: sine(t) + 0.001)
    out = tmp_path / "out"
    assert _cli(["compare", str(ref), str(run), "--out", str(out)]) == 0
    text = (out / "report.md").read_text()
    assert "| run |" in text and "overlay.png" in text and "error.png" in text
    assert (out / "overlay.png").stat().st_size > 1000 and (out / "error.png").stat().st_size > 1000
    merged = read_log(out / "merged.mcap")
    assert "/reference/hydroplant/cylinders/c" in merged and "/run/hydroplant/cylinders/c" in merged
    assert "| 1 | 1 |" in capsys.readouterr().out  # stroke max and RMS: 1 mm
    with pytest.raises(CircuitError, match="not found"):
        _cli(["compare", str(ref), str(tmp_path / "missing.mcap")])


def test_parse_runs_labels_and_errors():
    specs = compare.parse_runs("mujoco,mujoco:explicit,pbd-naive")
    assert [(s.mode, s.coupling, s.label) for s in specs] == [
        ("mujoco", "rosenbrock", "mujoco-rosenbrock"), ("mujoco", "explicit", "mujoco-explicit"),
        ("pbd-naive", "rosenbrock", "pbd-naive")]
    with pytest.raises(CircuitError, match="'bullet' is not one of"):
        compare.parse_runs("bullet")
    with pytest.raises(CircuitError, match="listed twice"):
        compare.parse_runs("mujoco,mujoco:rosenbrock")


# ---------------------------------------------------------------------------------------
# Convergence check
# ---------------------------------------------------------------------------------------


def test_convergence_check_rejects_a_pair_that_differs_by_more_than_the_tolerance(tmp_path):
    fine = write_log(tmp_path / "fine.mcap", 5e-4, 0.5, stroke=sine)
    close = write_log(tmp_path / "close.mcap", 1e-3, 0.5, stroke=lambda t: sine(t) + 5e-5)
    far = write_log(tmp_path / "far.mcap", 1e-3, 0.5, stroke=lambda t: sine(t) + 2e-3)
    assert check_convergence(close, fine).converged  # 0.05 mm < max(0.1 mm, 1e-3 × 200 mm)
    report = check_convergence(far, fine)
    assert not report.converged and {c.name for c in report.failures()} == {"stroke c", "joint j"}
    with pytest.raises(NotConvergedError, match=r"reference rejected: not converged.*stroke c changed by 2 mm.*allowed 0.2 mm"):
        require_converged(far, fine)
    assert require_converged(far, fine, Tolerance(relative=0.02)).converged


def test_convergence_check_rejects_a_diverged_run_and_a_wrong_step_ratio(tmp_path):
    fine = write_log(tmp_path / "fine.mcap", 5e-4, 0.5, stroke=sine, diverged_at=0.3)
    coarse = write_log(tmp_path / "coarse.mcap", 1e-3, 0.5, stroke=sine)
    with pytest.raises(NotConvergedError, match=r"the fine run \(step 0.0005 s\) is diverged at t = 0.3 s"):
        require_converged(coarse, fine)
    other = write_log(tmp_path / "other.mcap", 2.5e-4, 0.5, stroke=sine)
    with pytest.raises(NotConvergedError, match="not at h and h/2"):
        require_converged(coarse, other)


def test_seed_at_the_seeds_own_step_is_not_a_converged_reference(tmp_path):
    """Real runs of the seed cylinder at 1200 Hz and 2400 Hz: rejected, naming the stroke and the pressure."""
    from sim.run.runner import run

    h = 1 / 1200
    a = run(SEED, out=tmp_path / "h.mcap", overrides={"dt": h, "duration": 0.03})
    b = run(SEED, out=tmp_path / "h2.mcap", overrides={"dt": h / 2, "duration": 0.03})
    with pytest.raises(NotConvergedError, match=r"^reference rejected: not converged(?=.*stroke cyl changed by [0-9.e+]+ mm)(?=.*p_cap cyl changed by [0-9.e+]+ bar)"):
        require_converged(a.log_path, b.log_path)


def test_reference_is_computed_then_cached(tmp_path):
    """A loose-tolerance reference of 10 ms of the seed: converges within a few halvings, and comes back from the cache."""
    from sim.io.scenario import load_scenario

    scenario = load_scenario(SEED).with_overrides(duration=0.01)
    tol = Tolerance(relative=0.02)
    first = compute_reference(scenario, tolerance=tol, cache_dir=tmp_path / "cache", start_dt=1 / 4800)
    assert not first.cached and first.report.converged and first.dt < 1 / 4800
    assert all(c.change <= c.allowed for c in first.report.checks)
    assert read_log(first.log_path).metadata["hydroplant.run"]["coupling"] == "implicit"
    again = compute_reference(scenario, tolerance=tol, cache_dir=tmp_path / "cache", start_dt=1 / 4800)
    assert again.cached and again.log_path == first.log_path and again.runs == first.runs
    with pytest.raises(NotConvergedError, match="no converged reference within 1 halvings"):
        compute_reference(scenario, tolerance=Tolerance(relative=1e-6, stroke=1e-9, joint=1e-9, pressure=1.0),
                          cache_dir=tmp_path / "cache2", start_dt=1 / 4800, max_halvings=1)
    assert set(log_signals(first.log_path)) == {"joint x", "stroke cyl", "p_cap cyl", "p_rod cyl"}


def test_cli_bad_input_exits_2_through_the_hydroplant_command(tmp_path, monkeypatch, capsys):
    """Registered like the other tool modules, compare and tradeoff report bad input in one line with exit status 2."""
    import sim.cli

    def main(argv):  # an option argparse refuses exits with SystemExit(2), the others return 2
        try:
            return sim.cli.main(argv)
        except SystemExit as exc:
            return exc.code

    assert {"sim.tools.compare", "sim.tools.tradeoff"} <= set(sim.cli.TOOL_MODULES)
    ref = write_log(tmp_path / "ref.mcap", 1e-3, 0.1, stroke=sine)
    assert sim.cli.main(["compare", str(ref)]) == 2
    assert "needs a reference log and at least one more log" in capsys.readouterr().err
    assert sim.cli.main(["compare", str(SEED), "--methods", "mujoco:sideways"]) == 2
    assert "coupling 'sideways'" in capsys.readouterr().err
    assert main(["compare", str(SEED), "--filter-window", "-0.1"]) == 2
    assert "--filter-window: '-0.1' must be a positive finite number" in capsys.readouterr().err
    assert sim.cli.main(["compare", str(SEED), "--example", "boom/lift"]) == 2
    assert "not both" in capsys.readouterr().err
    assert sim.cli.main(["tradeoff", str(SEED), "--scheduler", "localhost:8786"]) == 2
    assert "not a scheduler address" in capsys.readouterr().err
    assert sim.cli.main(["tradeoff", str(tmp_path / "missing.scenario.toml")]) == 2
    assert "scenario file not found" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------
# Filtered (moving-average) metric: for signals that are not point-wise step-convergent
# ---------------------------------------------------------------------------------------


def test_moving_average_is_exact_for_a_line_and_damps_a_sine_by_its_sinc():
    """Centred window w: a line is unchanged; a·sin(ωt) becomes a·sinc(ωw/2)·sin(ωt); only whole windows are kept."""
    t = np.arange(0, 1.0 + 1e-9, 1e-4)
    times, mean = compare.moving_average(t, 3.0 + 2.0 * t, 0.1)
    assert times[0] == pytest.approx(0.05, abs=1e-9) and times[-1] == pytest.approx(0.95, abs=1e-9)
    assert np.max(np.abs(mean - (3.0 + 2.0 * times))) < 1e-12
    times, mean = compare.moving_average(t, np.sin(OMEGA * t), 0.1)
    gain = math.sin(OMEGA * 0.05) / (OMEGA * 0.05)
    assert np.max(np.abs(mean - gain * np.sin(OMEGA * times))) < 1e-6
    with pytest.raises(ValueError, match="window"):
        compare.moving_average(t, t, 0.0)


def test_filtered_metric_keeps_an_offset_and_gives_the_analytic_error_of_a_delay():
    """After a 0.1 s moving average: an offset stays the offset; a delay d of a·sin(ωt) gives 2a·sin(ωd/2)·sinc(ωw/2)."""
    t = np.arange(0, 1.0 + 1e-9, 1e-4)
    s = compare.filtered_error_stats(t, sine(t), t, sine(t) + 0.003, 0.1)
    assert s.max_abs == pytest.approx(0.003, rel=1e-9) and s.rms == pytest.approx(0.003, rel=1e-9)
    assert s.ref_range == pytest.approx(0.2, rel=1e-4)  # the unfiltered range, as for the point-wise metric
    d, w = 0.01, 0.1
    s = compare.filtered_error_stats(t, sine(t), t, sine(t - d), w)
    expected = 2 * 0.1 * math.sin(OMEGA * d / 2) * math.sin(OMEGA * w / 2) / (OMEGA * w / 2)
    assert s.max_abs == pytest.approx(expected, rel=1e-4)
    assert s.t_end == pytest.approx(1.0 - w / 2, abs=1e-9)


def test_filtered_metric_removes_chatter_that_the_point_wise_metric_sees():
    """Stick-slip-like chatter (±5 mm at 50 Hz, a whole number of periods per window) on a 0.5 mm offset:
    point-wise error 5.5 mm, filtered error the offset; different rates (1 kHz vs 300 Hz) change neither much."""
    chatter = lambda t: sine(t) + 5e-4 + 5e-3 * np.sin(2 * math.pi * 50 * t)  # noqa: E731
    t_ref = np.arange(0, 1.0 + 1e-9, 1e-4)
    assert error_stats(t_ref, sine(t_ref), t_ref, chatter(t_ref)).max_abs == pytest.approx(5.5e-3, rel=1e-3)
    s = compare.filtered_error_stats(t_ref, sine(t_ref), t_ref, chatter(t_ref), 0.1)
    assert s.max_abs == pytest.approx(5e-4, rel=1e-3)
    t = np.arange(0, 1.0 + 1e-9, 1 / 3000)
    assert compare.filtered_error_stats(t_ref, sine(t_ref), t, chatter(t), 0.1).max_abs == pytest.approx(5e-4, rel=0.05)


def test_filtered_convergence_check_accepts_chatter_the_point_wise_check_rejects(tmp_path):
    """A pair that differs by 50 Hz chatter of 2 mm: the point-wise check rejects it, the 0.1 s check accepts it
    and says so; a 2 mm offset is rejected by both (filtering is no licence for a shifted reference)."""
    fine = write_log(tmp_path / "fine.mcap", 5e-4, 0.5, stroke=sine)
    chatter = write_log(tmp_path / "chatter.mcap", 1e-3, 0.5, stroke=lambda t: sine(t) + 2e-3 * np.sin(2 * math.pi * 50 * t))
    far = write_log(tmp_path / "far.mcap", 1e-3, 0.5, stroke=lambda t: sine(t) + 2e-3)
    assert not check_convergence(chatter, fine).converged
    report = check_convergence(chatter, fine, filter_window=0.1)
    assert report.converged and report.filter_window == 0.1
    assert "averaged over a centred 0.1 s moving window" in report.text()
    with pytest.raises(NotConvergedError, match=r"not converged \(of the signals averaged over a centred 0.1 s"):
        require_converged(far, fine, filter_window=0.1)
    with pytest.raises(Exception, match="filter_window"):
        check_convergence(chatter, fine, filter_window=-1.0)


def test_compare_logs_reports_filtered_errors_and_percent_of_stroke(tmp_path):
    """compare_existing with a filter window writes the filtered table; circuit scales come from the attachment."""
    ref = write_log(tmp_path / "ref.mcap", 1e-3, 0.5, stroke=sine)
    run = write_log(tmp_path / "run.mcap", 1e-3, 0.5, stroke=lambda t: sine(t) + 1e-3)
    c = compare_logs(ref, run, filter_window=0.1)
    assert c.kind_stats("stroke", filtered=True)["max_abs"] == pytest.approx(1e-3, rel=1e-9)
    table = compare.percent_table([c], {"stroke": {"c": 0.5}, "relief_pa": 3.5e7})
    assert "0.2 (stroke c)" in table  # 1 mm of a 0.5 m stroke
    assert "pressure" in table.splitlines()[0]
    no_relief = compare.percent_table([c], {"stroke": {"c": 0.5}, "relief_pa": float("nan")})
    assert "pressure" not in no_relief.splitlines()[0] and "–" not in no_relief  # no relief: no column of dashes
    assert no_relief.splitlines()[2].split(" | ")[1:] == ["0.2 (stroke c)", "0.2 (stroke c) |"]
    result = compare.compare_existing([ref, run], tmp_path / "out", filter_window=0.1)
    assert "averaged over a centred 0.1 s moving window" in result.report_path.read_text()


def test_richardson_first_order_removes_an_error_proportional_to_the_step():
    """Runs at h and h/2 off the exact solution by C·h·g(t) (first order) on different grids: the extrapolation
    2·y(h/2) − y(h) returns the exact solution to interpolation error, the h/2 run alone is C·h/2·g off."""
    def exact(t):
        return np.sin(3.0 * t)

    def run(h, t):
        return exact(t) + 0.4 * h * np.cos(t)

    t_fine, t_coarse = np.linspace(0.0, 2.0, 4001), np.linspace(0.0, 2.0, 2001)
    h = 1e-2
    result = richardson_first_order(t_fine, run(h / 2, t_fine), t_coarse, run(h, t_coarse))
    assert np.max(np.abs(run(h / 2, t_fine) - exact(t_fine))) > 1e-3
    assert np.max(np.abs(result - exact(t_fine))) < 1e-5
