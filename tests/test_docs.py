"""The documentation states what the code does: generated reference pages current, documented ranges and
defaults those of the loaders, README's example runs, links resolve, no file speaks of development history."""

from __future__ import annotations

import dataclasses
import os
import re
from pathlib import Path

import pytest

from hydraulics.components import COMPONENT_TYPES
from sim.io.scenario import Scenario, ScenarioError, load_scenario
from sim.tools import docgen

ROOT = Path(__file__).resolve().parents[1]
BOOM = ROOT / "models" / "boom"


@pytest.mark.parametrize("name", sorted(docgen.PAGES))
def test_generated_reference_page_is_current(name):
    committed = (ROOT / "docs" / name).read_text(encoding="utf-8")
    assert committed == docgen.PAGES[name](), f"docs/{name} is out of date: run python -m sim.tools.docgen"


def test_docgen_check_reports_a_stale_page(tmp_path, capsys):
    (tmp_path / "components.md").write_text("old\n", encoding="utf-8")
    (tmp_path / "scenario-keys.md").write_text(docgen.scenario_reference(), encoding="utf-8")
    assert docgen.main(["--out", str(tmp_path), "--check"]) == 1
    assert "out of date: components.md" in capsys.readouterr().err
    assert (tmp_path / "components.md").read_text(encoding="utf-8") == "old\n"  # --check writes nothing
    assert docgen.main(["--out", str(tmp_path)]) == 0
    assert docgen.main(["--out", str(tmp_path), "--check"]) == 0


def test_every_component_field_has_a_unit_and_a_description():
    for kind, cls in COMPONENT_TYPES.items():
        docs = docgen.attribute_docs(cls)
        for f in dataclasses.fields(cls):
            assert f.metadata.get("unit"), f"{kind}.{f.name}: no unit in its param() metadata"
            assert docgen.field_description(f, docs), f"{kind}.{f.name}: no attribute docstring (the reference's description)"


def test_component_rows_carry_the_metadata():
    page = docgen.component_reference()
    cylinder = page[page.index("## cylinder"):page.index("## motor")]
    assert "| `bore` | m | (0, 1] | required | Piston diameter [m]. |" in cylinder
    assert "| `dead_volume_cap` | m^3 | [0, 1] | 0 |" in cylinder
    valve = page[page.index("## valve_4_3"):page.index("## relief_valve")]
    assert '| `centre` | - | `"closed"`, `"open"`, `"tandem"` | `"closed"` |' in valve
    assert "Ports: `P`, `T`, `A`, `B`; optional: `LS`." in valve


def _scenario(tmp_path, text: str) -> Path:
    path = tmp_path / "probe.scenario.toml"
    path.write_text(f'[scene]\nmjcf = "{BOOM / "boom.xml"}"\ncircuit = "{BOOM / "boom.circuit.toml"}"\n{text}',
                    encoding="utf-8")
    return path


# keys whose documented range holds beside another key's value (several hydraulic substeps: the implicit coupling)
BESIDE = {("run", "hydraulic_substeps"): 'coupling = "implicit"\n'}


def _accepts(tmp_path, table: str, key: str, value) -> bool:
    text = f"{key} = {value!r}" if not isinstance(value, str) else f'{key} = "{value}"'
    try:
        load_scenario(_scenario(tmp_path, f"[{table}]\n{BESIDE.get((table, key), '')}{text}\n"))
    except ScenarioError:
        return False
    return True


NUMERIC = [(t, k, a) for t, k, _, a, _, _ in docgen.scenario_keys() if re.fullmatch(r"(integer in )?[(\[][^,]+, [^\]]+\]", a)]


@pytest.mark.parametrize("table,key,allowed", NUMERIC, ids=[f"{t}.{k}" for t, k, _ in NUMERIC])
def test_documented_scenario_range_is_the_loaders(tmp_path, table, key, allowed):
    integer = allowed.startswith("integer in ")
    left, low, high = re.fullmatch(r"(?:integer in )?([(\[])([^,]+), ([^\]]+)\]", allowed).groups()
    low, high = float(low), float(high)
    if integer:
        low, high = int(low), int(high)
        assert _accepts(tmp_path, table, key, low) and _accepts(tmp_path, table, key, high)
        assert not _accepts(tmp_path, table, key, low - 1) and not _accepts(tmp_path, table, key, high + 1)
        assert not _accepts(tmp_path, table, key, low + 0.5)
        return
    assert _accepts(tmp_path, table, key, high)
    assert not _accepts(tmp_path, table, key, high * (1 + 1e-9))
    assert _accepts(tmp_path, table, key, low) == (left == "[")
    assert _accepts(tmp_path, table, key, low + (high - low) * 1e-6)


CHOICES = [(t, k, a) for t, k, _, a, attr, _ in docgen.scenario_keys() if a in ("MODES", "COUPLINGS", "STEPPER_NAMES", "FIDELITIES")
           and t == "run"]


@pytest.mark.parametrize("table,key,allowed", CHOICES, ids=[f"{t}.{k}" for t, k, _ in CHOICES])
def test_documented_scenario_choices_are_the_loaders(tmp_path, table, key, allowed):
    values = re.findall(r'`"([^"]+)"`', docgen._allowed(allowed))
    assert values
    for value in values:
        assert _accepts(tmp_path, table, key, value), f"[{table}] {key} = {value!r} refused"
    assert not _accepts(tmp_path, table, key, "no-such-value")


def test_documented_scenario_defaults_are_what_loading_gives(tmp_path):
    loaded = load_scenario(_scenario(tmp_path, ""))
    defaults = {f.name: f for f in dataclasses.fields(Scenario)}
    for _, key, _, _, attribute, _ in docgen.scenario_keys():
        if attribute is None:
            continue
        f = defaults[attribute]
        default = f.default if f.default_factory is dataclasses.MISSING else f.default_factory()
        assert getattr(loaded, attribute) == default, f"{key}: the page says {default!r}, loading gives {getattr(loaded, attribute)!r}"


def test_readme_is_short_and_its_library_example_runs(tmp_path, monkeypatch, capsys):
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme) <= 8000
    code = re.findall(r"```python\n(.*?)```", readme, re.S)
    assert len(code) == 1
    monkeypatch.chdir(tmp_path)
    exec(compile(code[0], "README.md", "exec"), {})
    out = capsys.readouterr().out
    assert out.startswith("complete real-time factor")
    assert "301 samples to t = 3.00 s" in out  # 3 s at the default 100 Hz log rate, both ends included
    assert [p.name[:len("boom-lift-mujoco-rosenbrock-")] for p in (tmp_path / "logs").glob("*.mcap")] == [
        "boom-lift-mujoco-rosenbrock-"]


def _links(path: Path):
    for target in re.findall(r"\]\(([^)\s]+)\)", path.read_text(encoding="utf-8")):
        if not re.match(r"[a-z]+:", target) and not target.startswith("#"):
            yield target.split("#")[0]


def test_relative_links_of_readme_and_docs_resolve():
    pages = [ROOT / "README.md", ROOT / "models" / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    missing = [f"{page.relative_to(ROOT)} -> {target}" for page in pages for target in _links(page)
               if not (page.parent / target).exists()]
    assert not missing, missing


HISTORY = re.compile(r"session [0-9]|sessions? [0-9]+[-–][0-9]+|issue #[0-9]|this[ ]session|/wor[k]/|\.\./share[d]", re.I)
SKIP = {"logs", "build", "dist", "__pycache__"}  # and every hidden folder (.git, .venv, caches)


def project_files(suffixes=(".py", ".md", ".toml")):
    """The project's own files with these suffixes (no virtual environment, caches, logs or build output)."""
    for folder, subfolders, names in os.walk(ROOT):
        subfolders[:] = [d for d in subfolders if not d.startswith(".") and d not in SKIP and not d.endswith(".egg-info")]
        yield from (Path(folder) / n for n in names if n.endswith(suffixes))


def test_no_file_speaks_of_development_history():
    found = []
    for path in project_files():
        for number, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            if HISTORY.search(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()[:100]}")
    assert not found, "\n".join(found)


def _run_all(monkeypatch):
    """bench/run_all.py as a module (bench/ is no package)."""
    import importlib.util
    import sys

    spec = importlib.util.spec_from_file_location("run_all", ROOT / "bench" / "run_all.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "run_all", module)  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_make_bench_rewrites_only_the_sections_it_ran(tmp_path, monkeypatch, capsys):
    run_all = _run_all(monkeypatch)
    (tmp_path / "bench").mkdir()
    (tmp_path / "bench" / "bench_a.py").write_text('print("median 4.2 us\\n| x | y |\\n|---|---|\\n| 1 | 2 |")\n')
    (tmp_path / "bench" / "bench_b.py").write_text('raise SystemExit("no MuJoCo here")\n')
    monkeypatch.setattr(run_all, "ROOT", tmp_path)
    monkeypatch.setattr(run_all, "BENCHES", (run_all.Bench("bench_a", (), "A", "About A."),
                                             run_all.Bench("bench_b", ("--quick",), "B", "About B.")))
    page = tmp_path / "benchmarks.md"
    page.write_text(run_all.page({"bench_a": run_all.section(run_all.BENCHES[0], "old A", "then"),
                                  "bench_b": run_all.section(run_all.BENCHES[1], "old B", "then")}))
    assert run_all.main(["--out", str(page), "--only", "bench_a"]) == 0
    text = page.read_text()
    assert "old A" not in text and "```text\nmedian 4.2 us\n```\n\n| x | y |\n|---|---|\n| 1 | 2 |\n<!-- /bench -->" in text
    assert "old B" in text  # a benchmark not run keeps its figures
    assert run_all.main(["--out", str(page), "--only", "bench_b"]) == 1
    text = page.read_text()
    assert "**Failed** with exit status 1" in text and "no MuJoCo here" in text and "old B" not in text
    assert "median 4.2 us" in text and text.index("## A") < text.index("## B")
    assert "`python bench/bench_b.py --quick`" in text
    capsys.readouterr()
