"""Test-only reference formulations (numpy, element-wise on arrays) of the package's compiled equations: the
oracles of the property tests.  Not part of the wheel; imported by the tests as ``from reference import laws``
(pytest puts ``tests/`` on the import path, as for ``conftest``).
"""
