"""JSON Schemas (draft 2020-12) of the ``--json`` documents of the command line: ``<command>.schema.json``.

Read one with :func:`sim.jsonout.schema`; the fields are described in docs/cli-json.md.
"""
