"""The model-fidelity ladder (``beambench bench models``): every beam model × integrator × timestep on the free
beam, speed against accuracy (``run``), and its tables and charts (``figures``)."""
