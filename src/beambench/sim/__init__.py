"""The MuJoCo twin: beam models, the scenes built from them, and the engines that step them.

- ``models``: the beams on ``MjSpec`` — ``beam`` (the :class:`~beambench.sim.models.beam.BeamModel` base and
  ``PRB3``, the paper's model), ``rod`` (segmented rods ``rod<N>[g][s]``), ``params`` (named parameter sets,
  ``sim_backend/<family>_<name>.yaml``), ``cosserat`` (the PyElastica cross-check) and ``registry`` (model name →
  family, parameters, builder: the one place that knows the names).
- ``scenes``: ``free_beam`` (clamp on a shaker stage), ``contact_rig`` (plus foot and force plate),
  ``contact_sweep`` (frequency sweeps of it), ``release`` (the release test), ``walker``, and ``drive`` (the
  :class:`~beambench.sim.scenes.drive.DrivenScene` base, the motor's speed ramp, the stage servo).
- ``engine``: ``stepping`` (chunked ``mujoco.rollout`` with precomputed controls, for the interactive rigs) and
  ``batch`` (many runs on a thread pool with ``mujoco.batch``, for sweeps and fits).
- ``selection``: the measured (model, integrator, timestep) tables and the cheapest choice within a tolerance.

The simulated devices and the sim rig that wires a scene to them live in :mod:`beambench.backends`. Nothing here is
imported by ``beambench`` at start-up (MuJoCo loads only when a sim rig or a study needs it).
"""
