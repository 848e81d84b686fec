"""``python -m hydroplant``: the ``hydroplant`` command (:mod:`sim.cli`) without the console script.

Example::

    python -m hydroplant run --example boom/lift --duration 1 --json
"""
