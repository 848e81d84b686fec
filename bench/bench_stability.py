"""Stability maps of the seed cylinder, the excavator and the boom, written to docs/stability/ (``make bench`` runs it).

    .venv/bin/python bench/bench_stability.py [--quick] [--scenes seed,excavator,boom] [--workers N]

Per scene and method: ``docs/stability/stability-<scene>-<method>.png`` (heat maps
of dt against bulk modulus, mass, dead volume and event; ≤ 150 kB each), plus
``<scene>.csv`` (every run) and ``<scene>-summary.txt`` (the stability boundary
per method).  Work files (variants, run cache) go to ``.cache/stability/<scene>``,
so a second call only re-plots (the cache is keyed on the simulation source too: after a change
to ``hydraulics/`` or ``sim/`` every run is made again).

Shortened, to keep the bench in minutes on two cores:

* seed (``closed`` scenario, no valves or pumps: β, mass and dead-volume sweeps with
  its own released-cylinder excitation): the default grid (dt 1e-5 … 1/30 s, 8 values),
  configurations 0.05 s long (≥ 11 periods of its 224 Hz column);
* excavator (``dig`` scenario): dt 1e-4, 1e-3, 3e-3, 1/120, 1/30 s; β 1e8 and 1e10;
  mass 1/100 and 100; dead volume 1e-7; all four events; configurations
  3 periods of the fastest (bucket, 21 Hz) column = 0.14 s; every run cut at
  1500 steps (none is: 1e-4 s needs 1400);
* boom (``lift`` scenario): the default grid, configurations 0.3 s long; every run cut at 5000 steps
  (the dt = 1e-5 s column covers 0.05 s; flagged ``*`` in the figures);
* ``--quick``: the tests' grid (3 dt values, runs ≤ 0.1 s).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim.tools import stability as st  # noqa: E402

PNG_LIMIT = 150_000  # B
SCENES = {
    "seed": (ROOT / "models" / "seed_cylinder" / "closed.scenario.toml", st.DEFAULT_GRID),
    "excavator": (
        ROOT / "models" / "excavator" / "dig.scenario.toml",
        replace(st.DEFAULT_GRID, dts=(1e-4, 1e-3, 3e-3, 1.0 / 120.0, 1.0 / 30.0), bulk_moduli=(1e8, 1e10),
                duration_max=0.15, max_steps=1500, pbd_max_steps=1500),
    ),
    "boom": (ROOT / "models" / "boom" / "lift.scenario.toml", st.DEFAULT_GRID),
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the tests' small grid")
    parser.add_argument("--scenes", default="seed,excavator,boom", help="comma-separated subset of " + ", ".join(SCENES))
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default: all cores)")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "stability")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for name in args.scenes.split(","):
        scenario, grid = SCENES[name]
        if args.quick:
            grid = st.QUICK_GRID
        work = ROOT / ".cache" / "stability" / (name + ("-quick" if args.quick else ""))
        start = time.perf_counter()
        result = st.stability_map(scenario, grid=grid, out_dir=work, workers=args.workers, progress=True)
        wall = time.perf_counter() - start
        scene = result.facts.scene
        for method, png in result.files.items():
            target = args.out / png.name
            shutil.copyfile(png, target)
            size = target.stat().st_size
            shown = target.relative_to(ROOT) if target.is_relative_to(ROOT) else target.name  # no machine's paths in the docs
            print(f"figure   {shown}  ({size / 1000:.0f} kB)")
            if size > PNG_LIMIT:
                print(f"warning: {target} is larger than {PNG_LIMIT / 1000:.0f} kB", file=sys.stderr)
        shutil.copyfile(work / "stability.csv", args.out / f"{scene}.csv")
        (args.out / f"{scene}-summary.txt").write_text(result.summary() + f"\n\nwall time {wall:.0f} s\n")
        runs = sum(1 for r in result.rows if not r["reference"])
        print(result.summary())
        print(f"{scene}: {runs} runs + {len(result.configs)} references in {wall:.0f} s wall\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
