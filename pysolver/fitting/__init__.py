"""Offline fitting tools: they write the model files the runtime stages read.

Nothing at run time imports this package (``tests/test_architecture.py``): a design reads the
committed model files, and only the command line runs these fits.

* :mod:`.material_fit`: the bracket material model from the tensile-test measurements
  (SI Note 3; ``make material`` -> ``pysolver/data/bracket_model.json``), with its pictures in
  :mod:`.material_report`;
* :mod:`.membrane_fit`: the linearised membrane model ``F_mem`` of temporal programming
  (SI Note 4; ``make membrane-model``), fitted to the one membrane energy on regular patches;
* :mod:`.cell_membrane`: membrane traction on a prescribed unit-cell patch from the
  simulator's own model and solver, the check of ``F_mem`` against the mechanics.
"""
