"""Calibration of a twin to measured or published results (``beambench calibrate sim``)."""
