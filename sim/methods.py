"""Method names: one spelling of "which solver, which coupling" for every command.

A *method* is a mode and a coupling, written ``MODE:COUPLING``::

    mujoco:implicit   mujoco:implicit-linear   mujoco:rosenbrock   mujoco:explicit
    pbd:implicit      pbd:rosenbrock           pbd:explicit        pbd-naive

* ``MODE`` alone means that mode at the default coupling (:data:`DEFAULT_COUPLING`, ``rosenbrock``, or
  the scenario's where a command says so): ``pbd`` is ``pbd:rosenbrock``.
* ``pbd-naive`` (the naive XPBD co-simulation) is always explicit, whatever coupling is given; its
  name carries none.
* ``pbd:COUPLING+blend``: PBD mode with its pressure forces blended by MuJoCo mode's θ-rule
  (``hydroplant run --pbd-blend``), e.g. ``pbd:rosenbrock+blend``.

``hydroplant run`` and ``inspect`` take ``--method MODE:COUPLING`` (or ``--mode`` and ``--coupling``
apart); ``compare`` and ``stability`` take ``--methods`` lists of these names; their reports and
``--json`` outputs name methods the same way.  The older dash spellings (``mujoco-implicit``,
``pbd-rosenbrock-blend``) are still read, with a one-line deprecation warning on stderr.

Where a method names a file or a Foxglove topic prefix, :attr:`Method.file_label` replaces ``:``
and ``+`` by ``-`` (``mujoco-implicit``).

This module imports nothing heavy: the command line's parsers use it before any simulation code loads.

Example::

    >>> parse_method("mujoco:explicit")
    Method(mode='mujoco', coupling='explicit', blend=False)
    >>> parse_method("pbd").name
    'pbd:rosenbrock'
"""

from __future__ import annotations

import sys
from collections import namedtuple

MODES = ("mujoco", "pbd", "pbd-naive")
"""Modes: MuJoCo steps the bodies, hydroplant's XPBD solver does, or the naive XPBD co-simulation."""
COUPLINGS = ("implicit", "explicit", "implicit-linear", "rosenbrock")
"""Couplings of the hydraulic network to the bodies (see docs/numerics.md)."""
DEFAULT_COUPLING = "rosenbrock"
"""The coupling of a scenario that names none and of a bare mode: one linearly implicit step per plant step.  It is
as stable as ``implicit`` on every cell of the stability maps of the seed cylinder, the boom and the excavator in
both modes, and closer to the converged reference on the dig's 0.1 s averages (docs/numerics.md)."""
NAIVE = "pbd-naive"
BLEND_SUFFIX = "+blend"
METHOD_HELP = ("MODE:COUPLING, MODE one of " + ", ".join(MODES) + " and COUPLING one of " + ", ".join(COUPLINGS)
               + f" (a bare MODE takes the {DEFAULT_COUPLING} coupling; pbd-naive has none; e.g. mujoco:implicit)")

MUJOCO_DEFAULT_METHODS = tuple(dict.fromkeys((f"mujoco:{DEFAULT_COUPLING}", "mujoco:implicit", "mujoco:explicit")))
PBD_DEFAULT_METHODS = tuple(dict.fromkeys((f"pbd:{DEFAULT_COUPLING}", "pbd:implicit", NAIVE)))
DEFAULT_METHODS_HELP = (f"default: {','.join(MUJOCO_DEFAULT_METHODS)}, plus {','.join(PBD_DEFAULT_METHODS)} when the "
                        "PBD plant imports")


def default_methods(pbd: bool) -> tuple:
    """The methods ``compare`` and ``stability`` run when none are named: the default coupling, ``implicit`` and
    ``explicit`` in MuJoCo mode, then, when ``pbd`` (the PBD plant imports), PBD mode at the default coupling and
    ``implicit`` and ``pbd-naive``."""
    return MUJOCO_DEFAULT_METHODS + (PBD_DEFAULT_METHODS if pbd else ())


class MethodError(ValueError):
    """A method name that is not one of :data:`MODES` × :data:`COUPLINGS`; the message names the allowed values."""


class Method(namedtuple("Method", "mode coupling blend", defaults=(False,))):
    """A mode, a coupling, and PBD mode's θ-rule blend (a named tuple: no dataclass machinery to import for --help)."""

    __slots__ = ()

    @property
    def name(self) -> str:
        """The canonical name: ``mujoco:implicit``, ``pbd:rosenbrock+blend``, ``pbd-naive``."""
        if self.mode == NAIVE:
            return NAIVE
        return f"{self.mode}:{self.coupling}" + (BLEND_SUFFIX if self.blend else "")

    @property
    def file_label(self) -> str:
        """The name where ``:`` and ``+`` may not stand (file names, topic prefixes): ``mujoco-implicit``."""
        return self.name.replace(":", "-").replace("+", "-")

    def __str__(self) -> str:
        return self.name


def _deprecated(text: str, method: Method, warn) -> Method:
    if warn is not None:
        warn(f"hydroplant: warning: method '{text}' is a deprecated spelling; write '{method.name}'")
    return method


def _stderr(message: str) -> None:
    print(message, file=sys.stderr)


def parse_method(text: str, default_coupling: str = DEFAULT_COUPLING, *, warn=_stderr) -> Method:
    """The :class:`Method` a name stands for; see the module docstring for the spellings.

    ``default_coupling``: the coupling of a bare mode.  ``warn(message)`` is called once for a
    deprecated dash spelling (default: one line on stderr; ``None``: silent).  Raises
    :class:`MethodError` naming the allowed values.
    """
    text = text.strip()
    if text in MODES:
        return Method(text, default_coupling)
    if ":" in text:
        mode, _, coupling = text.partition(":")
        blend = coupling.endswith(BLEND_SUFFIX)
        coupling = coupling.removesuffix(BLEND_SUFFIX)
        if mode not in MODES:
            raise MethodError(f"method {text!r}: mode {mode!r} is not one of {', '.join(MODES)}")
        if coupling not in COUPLINGS:
            raise MethodError(f"method {text!r}: coupling {coupling!r} is not one of {', '.join(COUPLINGS)}")
        if blend and mode != "pbd":
            raise MethodError(f"method {text!r}: '+blend' is a PBD-mode option (pbd:COUPLING+blend)")
        return Method(mode, coupling, blend)
    for mode in sorted(MODES, key=len, reverse=True):  # the dash spelling: mujoco-implicit, pbd-rosenbrock-blend
        if text.startswith(mode + "-"):
            rest = text.removeprefix(mode + "-")
            blend = rest.endswith("-blend") and mode == "pbd"
            coupling = rest.removesuffix("-blend") if blend else rest
            if coupling in COUPLINGS:
                return _deprecated(text, Method(mode, coupling, blend), warn)
    raise MethodError(f"method {text!r}: {text.partition('-')[0]!r} is not one of {', '.join(MODES)} (a method is MODE or "
                      f"MODE:COUPLING, COUPLING one of {', '.join(COUPLINGS)})")


def parse_methods(text: str, default_coupling: str = DEFAULT_COUPLING, *, warn=_stderr) -> list[Method]:
    """A comma-separated list of methods (:func:`parse_method` each); raises :class:`MethodError` for an empty list
    or a method listed twice."""
    items = [item.strip() for item in text.split(",") if item.strip()]
    if not items:
        raise MethodError(f"{text!r}: no method given; expected e.g. 'mujoco:implicit,mujoco:explicit,pbd'")
    out: list[Method] = []
    for item in items:
        method = parse_method(item, default_coupling, warn=warn)
        if method in out:
            raise MethodError(f"method {item!r} is listed twice")
        out.append(method)
    return out
