"""The CAN log formats a run can record (``--can-log``), without python-can: the input checks read them before
anything is opened."""

LOG_SUFFIXES = (".asc", ".blf", ".log", ".trc", ".csv")  # python-can writers that keep direction or ids
