"""The morphing simulator (SI Note 2) and its reports.

:mod:`sim.model` is the simulator: contact, physics options and time stepping
(``simulate_design``) of the shell mechanics of :mod:`pysolver.mechanics` (model assembly from
a design folder, energies, compiled kernels, the Newton solver); ``completion_times`` is in
:mod:`sim.model.collisions`.
:mod:`sim.report` is the check report (``check_morph``: the one verdict; pictures,
fabrication sheet, scan comparison); :mod:`sim.viewer` the data of the 3D morph viewer.
``sim`` reads the design folder only: it imports nothing from :mod:`pysolver` but the core
(``params``, ``errors``, ``core``, ``geometry``, ``tables``, ``progress``, ``records``,
``provenance``), the mechanics and the runtime material model (``tests/test_architecture.py``).
"""
