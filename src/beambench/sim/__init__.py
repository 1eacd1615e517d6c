"""The MuJoCo backend: beam models, scenes and simulated devices.

- ``params``: named beam parameter sets (``sim_backend/<model>_<name>.yaml``; ``sim.params`` in a protocol).
- ``beam``: beam builders on ``MjSpec`` (``PRB3``, the paper's model; ``SegmentedRod``, ``rod<N>``).
- ``contact_rig`` / ``walker``: the scenes; ``engine``: chunked stepping with ``mujoco.rollout``.
- ``devices`` / ``rig``: clock, motor, mocap and load cells satisfying ``beambench.devices.base``;
  ``build_sim_rig(protocol)`` is the entry point.

Nothing here is imported by ``beambench`` at start-up (MuJoCo loads only when a sim rig is built).
"""
