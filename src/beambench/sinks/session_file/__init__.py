"""The HDF5 session file: written during a run (``writer``), read back for analysis and notebooks (``reader``:
:func:`~beambench.sinks.session_file.reader.read_session`), checked against its schema (``schema``) and viewed as
pandas / xarray (``frames``). Layout: docs/session-format.md."""
