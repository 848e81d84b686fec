"""Static checks of the example scenes: a thin caller of ``hydroplant check --examples``.

Run: ``.venv/bin/python models/check_models.py`` (the same as ``hydroplant check --examples``);
see :mod:`sim.tools.check` for what is checked.  Exit status 0 when every check passes.
"""

from sim.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["check", "--examples"]))
