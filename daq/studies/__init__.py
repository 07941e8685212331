"""The offline studies: one room each, over logs and rigs (docs/architecture.md).

The service (daq/ root: recording and replay) never imports a study; a study never imports the CLI.
"""
