"""Where batches go: the session file (:mod:`beambench.sinks.session_file`, HDF5 written and read) and the live
view (:mod:`beambench.sinks.viewer`, Rerun). The two never import each other."""
