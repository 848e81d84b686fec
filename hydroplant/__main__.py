"""``python -m hydroplant ...`` runs the ``hydroplant`` command line (:func:`sim.cli.main`)."""

import sys

from sim.cli import main

if __name__ == "__main__":
    sys.argv[0] = "hydroplant"
    raise SystemExit(main())
