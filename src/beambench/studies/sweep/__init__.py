"""Parameter sweeps on the sim backend (``beambench sweep``): the sweep file, its plan and run into one results
table (``run``), how one task of jobs runs on a scene's batched engine and what it measures (``task``) and the
sweep's chart (``figure``)."""
