"""``hydroplant check`` on the shipped scenes and the loop-closure test scenes: numbers and verdicts."""

from __future__ import annotations

import re
import shutil
from pathlib import Path


from sim import cli
from sim.tools.check import check_scene

SCENES = Path(__file__).parent / "scenes"


def test_check_passes_on_every_shipped_scene_and_the_test_scenes(capsys):
    code = cli.main(["check", "--examples", str(SCENES / "hold.scenario.toml"), str(SCENES / "hold_links.scenario.toml"),
                     str(SCENES / "hlink.scenario.toml")])
    out = capsys.readouterr().out
    assert code == 0, out
    assert out.rstrip().endswith("all checks passed")
    # the excavator's figures quoted in models/excavator/README.md
    assert "boom_cyl: LMIN 1.9540 LMAX 3.2880 m (stroke 1.334 m) | start L = 2.8020 m (63.6 % stroke), dL/dboom = +0.7875 m" in out
    assert "boom_cyl: F = +341.466 kN -> cap 151.0 bar gauge" in out


def test_check_reports_the_loop_closure_and_the_same_numbers_with_pins_on_the_links():
    barrel_rod, problems = check_scene(SCENES / "hold.scenario.toml")
    links, _ = check_scene(SCENES / "hold_links.scenario.toml")
    assert problems == 0
    assert "equality rod_eye: violation 0.0998 at the set pose, 0 after projection" in barrel_rod
    for text in (barrel_rod, links):  # the driving joint is the arm, whichever bodies carry the pins
        assert "start L = 1.0270 m (69.3 % stroke), dL/darm_hinge = +0.8237 m" in text
        assert "lift_cyl: F = +5.436 kN -> cap 10.8 bar gauge" in text
        assert "valve 'lift_valve' +1 -> extends" in text


def test_check_flags_a_joint_range_past_the_stroke_and_a_hold_beyond_the_relief(tmp_path, capsys):
    for name in ("hold.scenario.toml", "loop.circuit.toml"):
        shutil.copy(SCENES / name, tmp_path / name)
    xml = (SCENES / "loop_arm.xml").read_text().replace('range="-0.2218 0.2531"', 'range="-0.5 0.8"')
    (tmp_path / "loop_arm.xml").write_text(xml.replace('mass="100" diaginertia="1 1 1"', 'mass="8000" diaginertia="1 1 1"'))
    text, problems = check_scene(tmp_path / "hold.scenario.toml")
    assert problems >= 2
    assert re.search(r"sweep arm_hinge \[-0.5000, \+0.8000\]: L in \[0.49\d\d, 1.53\d\d\] m OUTSIDE the stroke.*!!", text)
    assert re.search(r"lift_cyl: F = \+\d+\.\d+ kN -> cap \d+\.\d bar gauge = \d+ % of relief 'relief' \(200 bar\)  !!", text)
    assert cli.main(["check", str(tmp_path / "hold.scenario.toml")]) == 1


def test_check_without_a_scenario_is_bad_input(capsys):
    assert cli.main(["check"]) == 2
    assert "check: give a SCENARIO file, --example NAME or --examples" in capsys.readouterr().err


def test_check_grid_finds_the_worst_hold_over_the_joint_range():
    text, problems = check_scene(SCENES / "hold.scenario.toml", grid=9)
    assert problems == 0
    line = next(l for l in text.splitlines() if l.startswith("    lift_cyl") and " at arm_hinge " in l)
    # worst at the top of the arm's range: the extended-end hold of the sweep
    assert line.startswith("    lift_cyl: F = +5.603 kN -> cap 11.1 bar gauge") and line.endswith("at arm_hinge +0.253")


def test_check_for_pbd_mode_names_what_pbd_mode_drops(capsys):
    assert cli.main(["check", "--mode", "pbd", str(SCENES / "hlink.scenario.toml")]) == 0
    out = capsys.readouterr().out
    assert "body 'base' has free joint 'base_free', held by weld 'base_weld'" in out and "geom(s) 'cab' (mesh)" in out


def test_the_stroke_end_pose_is_on_the_stroke_end_not_the_nearest_sweep_point(tmp_path):
    """The boom's hinge range widened past its cylinder's extended end (flagged): the extended pose is found where
    L = LMAX between the sweep's points, so its hold is the boom's own (18.03 kN, as with the range that ends there)
    and not the end stop's push 0.8 mm beyond it."""
    models = Path(__file__).parent.parent / "models" / "boom"
    for f in models.iterdir():
        if f.is_file():
            shutil.copy(f, tmp_path / f.name)
    xml = tmp_path / "boom.xml"
    xml.write_text(xml.read_text().replace('range="-0.2448 0.7710"', 'range="-0.2448 0.9"'))
    text, problems = check_scene(tmp_path / "hold.scenario.toml")
    assert problems == 1 and "OUTSIDE the stroke" in text  # the range, flagged; nothing else
    assert re.search(r"extended: boom_hinge = \+0\.771\d, L = 1\.0600 m", text), text
    hold = text.split("holding at boom_cyl extended")[1].splitlines()[1]
    assert hold.startswith("    boom_cyl: F = +18.03") and "!!" not in hold, hold
