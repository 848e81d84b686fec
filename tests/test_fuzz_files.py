"""A fuzz battery of damaged scene files through ``hydroplant run``: a clean run or one line naming the file.

Each case copies a small scene (the seed cylinder or the boom), damages one of its three files
-- the scenario, the circuit or the MJCF -- by one mutation, and runs ``hydroplant run`` on it
in-process (one step size, a few steps) under a wall-clock limit.  Mutations:

* TOML (scenario, circuit): a leaf value replaced (zero, negative, huge, tiny, NaN, inf, a huge
  integer, a boolean, a string, an array, a table), a key deleted, a whole table deleted;
* MJCF: an attribute's value replaced (NaN, inf, negative, huge, text, empty), an attribute
  deleted, an element deleted;
* any file: cut at a random byte, random bytes (NUL and non-UTF-8 among them) written into it,
  or replaced by random bytes.

Every case must end in exit 0 (a clean run), exit 3 (a run the divergence checks or the
plausibility monitor stopped: a valid but absurd input, e.g. the seed scenario without its
``[monitor] enabled = false``) or exit 2 with exactly one line on stderr that names the damaged
file; never a traceback, never past its time limit.  The cases are
drawn by hypothesis from a fixed seed (``derandomize``), so the battery is the same on every run;
its size is bounded so that it takes well under a minute on one core.
"""

from __future__ import annotations

import contextlib
import io
import random
import shutil
import signal
import time
import tomllib
import xml.etree.ElementTree as ET
from collections import Counter

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import MODELS
from sim import cli
from sim.tools.stability import dump_toml

SCENES = {"seed_cylinder": ("closed.scenario.toml", "seed_cylinder.circuit.toml", "seed_cylinder.xml"),
          "boom": ("hold.scenario.toml", "boom.circuit.toml", "boom.xml")}
CASES = 400  # cases of the battery
CASE_LIMIT_S = 10.0  # wall-clock limit of one case [s]
BATTERY_LIMIT_S = 60.0  # the whole battery [s]
RUN_ARGS = ("--dt", "1e-3", "--duration", "5e-3", "--no-progress")
NUMBERS = [0, -1, 1e300, -1e300, 1e-300, 5e-324, float("nan"), float("inf"), -float("inf"), 10**30, 2, 0.5]
OTHER_VALUES = [True, False, "", "abc", [], [1, 2], {"a": 1}]
XML_VALUES = ["nan", "inf", "-inf", "-1", "0", "1e300", "abc", "", "1 2", "0 0 0 0 0 0 0 0 0 0"]
TRACEBACK = "Traceback (most recent call last)"


class CaseTimeout(BaseException):
    """A case ran past :data:`CASE_LIMIT_S`."""


def _alarm(signum, frame):
    raise CaseTimeout


def _leaves(node, prefix=()):
    """Paths to every value of a parsed TOML document (tables and arrays of tables walked)."""
    if isinstance(node, dict):
        for key, value in node.items():
            yield (*prefix, key)
            yield from _leaves(value, (*prefix, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            if isinstance(value, dict):
                yield from _leaves(value, (*prefix, i))


def _parent(doc, path):
    for key in path[:-1]:
        doc = doc[key]
    return doc


def mutate_toml(text: str, rng: random.Random) -> str:
    doc = tomllib.loads(text)
    paths = list(_leaves(doc))
    path = rng.choice(paths)
    parent = _parent(doc, path)
    if rng.random() < 0.2:
        del parent[path[-1]]
    else:
        parent[path[-1]] = rng.choice(NUMBERS + OTHER_VALUES)
    return dump_toml(doc)


def mutate_xml(text: str, rng: random.Random) -> str:
    root = ET.fromstring(text)
    elements = list(root.iter())
    with_attributes = [e for e in elements if e.attrib]
    kind = rng.random()
    if kind < 0.2 and len(elements) > 1:
        victim = rng.choice(elements[1:])
        for parent in root.iter():
            if victim in list(parent):
                parent.remove(victim)
                break
    else:
        element = rng.choice(with_attributes)
        attribute = rng.choice(sorted(element.attrib))
        if kind < 0.35:
            del element.attrib[attribute]
        else:
            element.set(attribute, rng.choice(XML_VALUES))
    return ET.tostring(root, encoding="unicode")


def mutate_bytes(data: bytes, rng: random.Random) -> bytes:
    kind = rng.randrange(3)
    if kind == 0:
        return data[: rng.randrange(len(data))]
    garbage = bytes(rng.choice([0, 0xFF, 0xC3, 0x80, rng.randrange(256)]) for _ in range(rng.randint(1, 16)))
    if kind == 1:
        at = rng.randrange(len(data))
        return data[:at] + garbage + data[at:]
    return garbage * rng.randint(1, 8)


def run_case(folder, scene, target, operator, seed):
    """One case: (outcome, detail); outcome is 'clean', 'error', 'stopped', 'traceback', 'hang' or 'bad'."""
    rng = random.Random(seed)
    scenario_name = SCENES[scene][0]
    path = folder / SCENES[scene][target]
    data = path.read_bytes()
    if operator == "bytes":
        path.write_bytes(mutate_bytes(data, rng))
    elif target == 2:
        path.write_text(mutate_xml(data.decode(), rng))
    else:
        path.write_text(mutate_toml(data.decode(), rng))
    out, err = io.StringIO(), io.StringIO()
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, CASE_LIMIT_S)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = cli.main(["run", str(folder / scenario_name), "--out", str(folder / f"{seed}.mcap"), *RUN_ARGS])
            except SystemExit as exc:
                code = exc.code
            except CaseTimeout:
                return "hang", path.name
            except Exception as exc:  # noqa: BLE001 - what the battery looks for
                return "traceback", f"{path.name}: {type(exc).__name__}: {exc}"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    text = out.getvalue() + err.getvalue()
    lines = [line for line in err.getvalue().splitlines() if line.strip()]
    if TRACEBACK in text:
        return "traceback", text
    if code == 0 and not lines:
        return "clean", ""
    if code == 3 and not lines and "status" in out.getvalue():
        return "stopped", ""
    if code == 2 and len(lines) == 1 and lines[0].startswith("hydroplant: error: ") and path.name in lines[0]:
        return "error", lines[0]
    return "bad", f"exit {code}: {text!r}"


CASE = st.tuples(st.sampled_from(sorted(SCENES)), st.sampled_from([0, 1, 2]), st.sampled_from(["value", "bytes"]),
                 st.integers(0, 2**32 - 1))


def test_fuzz_battery_of_damaged_scene_files(tmp_path_factory):
    """:data:`CASES` damaged scenes: every one a clean run, a stopped run or one line naming a file; the counts are printed."""
    counts, failures, started = Counter(), [], time.perf_counter()
    pristine = {scene: tmp_path_factory.mktemp(f"pristine-{scene}") for scene in SCENES}
    for scene, folder in pristine.items():
        shutil.copytree(MODELS / scene, folder, dirs_exist_ok=True)

    @settings(max_examples=CASES, derandomize=True, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(case=CASE)
    def one(case):
        scene, target, operator, seed = case
        folder = tmp_path_factory.mktemp("case")
        shutil.copytree(pristine[scene], folder, dirs_exist_ok=True)
        outcome, detail = run_case(folder, scene, target, operator, seed)
        counts[outcome] += 1
        counts["cases"] += 1
        if outcome in ("traceback", "hang", "bad"):
            failures.append((case, outcome, detail[:400]))
        shutil.rmtree(folder, ignore_errors=True)

    one()
    elapsed = time.perf_counter() - started
    print(f"\nfuzz battery: {counts['cases']} cases, {counts['error']} clear errors, {counts['clean']} clean runs, "
          f"{counts['stopped']} stopped runs, {counts['traceback']} tracebacks, {counts['hang']} hangs, "
          f"{counts['bad']} other, {elapsed:.1f} s")
    assert not failures, failures[:5]
    assert counts["cases"] == CASES
    assert counts["error"] > 0 and counts["clean"] > 0  # both outcomes are exercised
    assert elapsed < BATTERY_LIMIT_S
