"""``gvt import``: measurements recorded by other tools (UFF, CSV, NI TDMS, HDF5) into a gvtlink log (issue 31).

Each source format is one module that reads a file into :class:`daq.studies.importing.data.TimeImport` or
:class:`daq.studies.importing.data.FrfImport`; one writer turns either into a format-2 log, so every verb works on
imported data exactly as on a recording."""
