"""beambench: test-bench control and data acquisition for soft twisted-beam walking robots.

``beambench run PROTOCOL`` records a frequency sweep (motion capture, load cells, motor telemetry on one clock)
into an HDF5 session, on a MuJoCo twin of the rig (``sim``), emulated devices or the real rig; ``beambench
--help`` lists the other commands. In a notebook::

    from beambench.sinks.session_file.reader import read_session
    from beambench.analysis import resample_session

    s = read_session("data/contact_sweep_sim_….h5")
    mocap = s.to_pandas("mocap")   # one row per frame: foot_x … foot_z, frame, step; units in mocap.attrs["units"]
    ds = s.to_xarray()             # the whole session: position (time, marker, axis), load cells, motor, /general
    df = resample_session(s, 1000) # every stream on one clock-corrected 1 kHz timeline, with the step index

Packages, top to bottom (imports point down): ``commands`` (the CLI), ``studies`` (fits and sweeps on the sim),
``session`` (one run wired together), ``backends`` (the sim, emulated and hardware rigs) and ``analysis``, ``sinks``
(the session file, the live view) and ``emulators``, ``sim`` and ``devices``, ``acquisition`` (batches, streams,
protocol, runner), ``common``; docs/architecture.md draws the pipeline.
"""

__version__ = "0.1.0"
