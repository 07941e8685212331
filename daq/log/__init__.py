"""Session logs: MCAP layout, writer thread, readers, recovery and export (docs/log-format.md)."""
