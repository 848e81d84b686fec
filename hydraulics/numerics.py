"""Numerical settings of the network's solvers: Newton iteration, line search, trust region, pressure inversion,
the linearisation's velocity guess.

One home for these numbers, imported by the modules that document and use them (:mod:`hydraulics.steppers`,
:mod:`hydraulics.coupling`, :mod:`hydraulics.network`) and by :func:`hydraulics._compiled.pack_network`, which
writes them into the packed arrays the kernels read at run time (so a changed value needs no recompile).  This
module imports nothing: the solver modules and the kernels depend on it, never the reverse.

Example
-------
>>> NEWTON_PRESSURE_TOLERANCE + NEWTON_RELATIVE_TOLERANCE * 2e7  # convergence bound at 200 bar [Pa]
0.0102
"""

# Newton's method of the backward-Euler step (hydraulics.steppers.StepperImplicitEuler)
NEWTON_MAX_ITERATIONS = 30
"""Newton iterations per (sub)step before the step is reported failed; the excavator needs 2–4."""
NEWTON_PRESSURE_TOLERANCE = 1e-2
"""Largest pressure change of the last Newton update [Pa] (absolute part of the convergence test)."""
NEWTON_RELATIVE_TOLERANCE = 1e-11
"""Largest pressure change of the last Newton update relative to the node pressure [-]."""
LINE_SEARCH_HALVINGS = 8
"""Backtracking halvings when the residual does not decrease enough."""
SUFFICIENT_DECREASE = 0.3
"""Armijo-type sufficient decrease of the max-norm residual per unit step [-].  Strong (0.3 rather than the
textbook 1e-4) because an orifice's square-root law makes full Newton steps flip the sign of Δp and ping-pong
(for Q ∝ sign(Δp)·√|Δp| Newton maps Δp to −Δp): the half step the rule then takes lands on the root."""
TRUST_PRESSURE = 2e6
"""Trust region of one Newton update [Pa]: a node may fill its vapour void and then change by at most
max(TRUST_PRESSURE, TRUST_FRACTION·|p|), which keeps the iteration from jumping out of cavitation to absurd
pressures after a valve slam."""
TRUST_FRACTION = 0.5
"""Relative part of the trust region [-] (see :data:`TRUST_PRESSURE`)."""

# Linear algebra of the Newton solves (hydraulics._compiled.sparse_pattern)
SPARSE_FACTORISATION = True
"""Factor the Newton matrix over its sparse pattern: elimination restricted to the entries the circuit's branches
and their fill-in make, O(n) on a circuit of many blocks joined through one supply gallery.  False: dense Gaussian
elimination with partial pivoting (for comparison; O(n²) per solve, n the free nodes).  Both give the same results
where partial pivoting keeps the diagonal; where it would exchange rows, the sparse path hands over to the dense one."""

# Pressure inversion of compliant nodes (elastic walls, accumulators; hydraulics.network)
PRESSURE_INVERSION_MAX_ITERATIONS = 60
"""Newton iterations of a compliant node's pressure inversion; it converges in fewer than 8 from the rigid guess."""
PRESSURE_INVERSION_TOLERANCE = 1e-13
"""Convergence bound on ln(V·φ/m) [-]."""

# Velocity guess of the implicit couplings' linearisation (hydraulics.coupling)
GUESS_VOLUME_FRACTION = 0.01
"""A start velocity is the linearisation's guess of v⁺ only where the guessed displacement h·|v| changes each
chamber volume of its cylinder by at most this fraction [-] (a short chord of the pressure law): in an unresolved
oscillation (the seed at 1200 Hz reverses ~1900 m/s every step) the start velocity is a bad guess of v⁺, and the
law linearised there lets the machine gain energy."""
