"""Force arithmetic: load-cell calibration (counts to newtons) and contact detection from forces."""
