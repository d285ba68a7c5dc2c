"""The morphing simulator (SI Note 2) and its reports.

Modules: :mod:`sim.model` (assembly from a design folder), :mod:`sim.energies` (energies,
gradients, Hessians, rigid-body reduction), :mod:`sim.kernels` (compiled assembly loops),
:mod:`sim.solver` (Newton, CHOLMOD), :mod:`sim.simulate` (time stepping, ``frames.npz``,
``simulate_design``, ``completion_times``), :mod:`sim.cell_membrane` (membrane traction on a
unit cell), :mod:`sim.synthetic` (test shells, stand-in bracket law); and the report side
(:mod:`sim.report`, :mod:`sim.collisions`, :mod:`sim.scan`).
"""
