"""Identifying a beam model from a release test (``beambench fit``): the fit itself (``release``: load the session,
differential evolution, the written parameter set), what it searches (``space``), its least-squares refinement and
confidence intervals by ``mujoco.sysid`` (``sysid``) and its figure (``figure``)."""
