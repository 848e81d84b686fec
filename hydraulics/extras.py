"""Optional dependencies: the libraries an extra of the ``hydroplant`` distribution brings, imported when needed.

The default install (numpy, mujoco, mcap, zstandard, numba) runs every scene in both modes and writes and reads
logs.  The tools need more, each from one extra (``pyproject.toml``, ``[project.optional-dependencies]``):

========  ==================================  ==================================================================
extra     libraries                           needed by
========  ==================================  ==================================================================
tools     matplotlib, scipy                   ``compare``, ``tradeoff``, ``stability`` (figures); the ``reference``
                                              stepper and :func:`hydraulics.load.simulate_reference` (scipy)
dask      dask[distributed], bokeh            sweeps on a Dask cluster and its dashboard
live      foxglove-sdk                        the live view of a running machine
gamepad   pygame                              a gamepad as the operator's input
hdf5      h5py                                HDF5 export of logs
========  ==================================  ==================================================================

:func:`require` imports a module of an extra or raises :class:`MissingExtra`, a
:class:`~hydraulics.components.CircuitError`: the command line prints its one line and exits with status 2.

Example
-------
>>> from hydraulics.extras import require
>>> require("numpy", "tools", "this example").__name__
'numpy'
>>> require("no_such_module_here", "tools", "hydroplant compare")
Traceback (most recent call last):
...
hydraulics.extras.MissingExtra: hydroplant compare needs the [tools] extra: pip install 'hydroplant[tools]'
"""

from __future__ import annotations

import importlib

from hydraulics.components import CircuitError

EXTRAS = {
    "tools": ("matplotlib", "scipy"),
    "dask": ("dask", "distributed", "bokeh"),
    "live": ("foxglove",),
    "gamepad": ("pygame",),
    "hdf5": ("h5py",),
}
"""The importable modules each extra brings."""


class MissingExtra(CircuitError):
    """A library of an extra is not installed; the message names the extra and the command that installs it."""


def require(module: str, extra: str, what: str):
    """The imported ``module``, or :class:`MissingExtra` naming ``what`` needs it (one line: ``<what> needs the
    [<extra>] extra: pip install 'hydroplant[<extra>]'``)."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingExtra(f"{what} needs the [{extra}] extra: pip install 'hydroplant[{extra}]'") from None
