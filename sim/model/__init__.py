"""The simulator proper: time stepping of the shell mechanics read from the design folder.

The mechanics it steps (model assembly from the design tables and ``model.npz``, energies,
kernels, the Newton solver, the rim margin) are :mod:`pysolver.mechanics`, shared with the
membrane model of temporal programming.  Modules here: :mod:`.contact`, :mod:`.physics`,
:mod:`.collisions` (``completion_times``, the one completion rule) and :mod:`.simulate`
(``simulate_design``).
"""
