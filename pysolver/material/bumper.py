"""The modulus of the printed polymer in hot water, for the bumpers of closed cells.

The bumpers and the bases are printed in the same shape-memory photopolymer as the brackets,
so once a cell has closed, its bumpers are pressed together by the membrane in 56 C water in
which that polymer is as soft as the brackets' creep tests show.  The reference simulator
replaces a closed bracket by a numerical penalty spring (``kappa_c`` = 199.8 N/mm, "a high
stiffness constant", SI Note 2); :mod:`sim.model.physics` (``bumper_compliance``) gives it
instead the axial stiffness of the printed bumper pair, ``E A / L``, with ``E`` from here.

The modulus comes from the unit-cell tests (``data/material-measurements``), read through a
beam model of the V-bracket: each of the cell's four V-brackets is two arms of length
``a = b / (2 cos alpha)``, clamped at the base and meeting at the apex, where the mirror
symmetry of the V keeps their slope; an axial shortening ``d`` of the cell bends each arm by
``d / (2 sin alpha)`` across its length, so a cell of in-plane section ``w x h`` (``w`` the
1 mm bracket height) has the stiffness ``k = 2 E w h^3 / (a^3 sin^2 alpha)``.  This is
elementary (Euler-Bernoulli, small deflection) and is checked on the dry tests, where it
gives about the same modulus for every long cell (``dry_modulus``, ``l >= 8`` mm: 2.5-4.4 GPa
and one 8.3 GPa, median 3.1 GPa, a rigid photopolymer's) once the test rig's compliance is
taken off: the shortest cells (``l`` = 5 mm, whose brackets alone would be 20-100x stiffer
than measured) give that compliance, 0.032 mm/N.

In water the same formula on the creep tests at the two smallest loads (1 and 2 N), long
cells (``l >= 7`` mm) and small deflection (``x < b / 2``) gives the effective (creep)
modulus ``E(t) = F / (x(t) - c_rig F) * a^3 sin^2 alpha / (2 w h^3)`` at each time in water;
its median over the series falls from 0.38 GPa at 5 s to 16 MPa at 120 s
(:data:`pysolver.params.BUMPER_MODULUS`; the series that collapse leave the sample, so the
late medians lean to the stiffer series).  Nothing in the tests separates the polymer's
warming in the water from its creep under load; both act on a bumper that has been in the
water as long, so the effective modulus is used as it is.
"""

from __future__ import annotations

import math

import numpy as np

from pysolver.params import BUMPER_MODULUS, UNIT_CELL

RIG_LENGTH_MM = 5.0
"""Central length of the cells whose dry compliance is the test rig's (the shortest)."""
DRY_MIN_LENGTH_MM = 8.0
"""Central lengths from which the dry cells' compliance is the brackets' (bending)."""
WET_MIN_LENGTH_MM = 7.0
"""Central lengths from which the wet (creep) cells are read for the modulus."""
WET_MAX_LOAD_N = 2.0
"""Largest nominal creep load read (the smallest loads stay closest to small deflection)."""
SMALL_DEFLECTION = 0.5
"""A creep series is read while its displacement is below this fraction of ``b``."""
DRY_FORCE_RANGE_N = (2.0, 8.0)
"""Force window of the dry ramp in which the cell's stiffness is the fitted slope."""
DRY_TIME_CUT_S = 5.25
"""The dry ramp ends here (the 10 N hold and the snap-through of ``0.35_9`` after it)."""


def v_bracket_factor(h, b, unit=UNIT_CELL):
    """``E = k * factor`` for a cell of four V-brackets (the beam model above).

    Parameters
    ----------
    h : float or (n,) float, mm -- bracket thickness
    b : float or (n,) float, mm -- bracket length

    Returns
    -------
    float or (n,) float, mm^-1 (MPa per N/mm)
    """
    al = unit.alpha_rad
    a = np.asarray(b, float) / (2.0 * math.cos(al))
    return a ** 3 * math.sin(al) ** 2 / (2.0 * unit.bracket_w * np.asarray(h, float) ** 3)


def _dry_slopes(dry):
    """Per dry series: ``(h, l, b, stiffness N/mm)`` of the ramp (force window, least squares)."""
    out = []
    lo, hi = DRY_FORCE_RANGE_N
    for _k, _name, sl in dry.series_slices():
        F, x, t = dry.force[sl], dry.x[sl], dry.time[sl]
        m = (t < DRY_TIME_CUT_S) & (F > lo) & (F < hi)
        k = float(np.polyfit(x[m], F[m], 1)[0])
        out.append((float(dry.h[sl][0]), float(dry.l[sl][0]), float(dry.b[sl][0]), k))
    return out


def rig_compliance(dry) -> float:
    """Compliance of the test rig, mm/N: the median of the shortest dry cells' compliance.

    Parameters
    ----------
    dry : pysolver.material.measurements.TestTable
    """
    c = [1.0 / k for h, l, b, k in _dry_slopes(dry) if abs(l - RIG_LENGTH_MM) < 1e-6]
    return float(np.median(c))


def dry_modulus(dry) -> np.ndarray:
    """The polymer's dry modulus from every long dry cell (beam model, rig taken off), MPa.

    Returns
    -------
    (n,) float, MPa -- one per dry series with ``l >= DRY_MIN_LENGTH_MM``
    """
    c_rig = rig_compliance(dry)
    E = [v_bracket_factor(h, b) / (1.0 / k - c_rig)
         for h, l, b, k in _dry_slopes(dry) if l >= DRY_MIN_LENGTH_MM - 1e-6]
    return np.asarray(E, float)


def wet_modulus(meas, times) -> tuple[np.ndarray, np.ndarray]:
    """Median effective modulus of the polymer at each time in water, MPa.

    Parameters
    ----------
    meas : pysolver.material.measurements.Measurements
    times : (m,) float, s -- time since the start of the creep test

    Returns
    -------
    E : (m,) float, MPa -- median over the series read at that time
    n : (m,) int -- series read (long cells, loads <= 2 N, deflection below b/2)
    """
    wet, c_rig = meas.wet, rig_compliance(meas.dry)
    times = np.asarray(times, float)
    vals = [[] for _ in times]
    for _k, _name, sl in wet.series_slices():
        h, l, b, F = wet.h[sl][0], wet.l[sl][0], wet.b[sl][0], wet.nominal[sl][0]
        if l < WET_MIN_LENGTH_MM - 1e-6 or F > WET_MAX_LOAD_N + 1e-6:
            continue
        t, x = wet.time[sl], wet.x[sl]
        for j, tj in enumerate(times):
            i = int(np.searchsorted(t, tj))
            if i < len(t) and x[i] < SMALL_DEFLECTION * b:
                vals[j].append(F / (x[i] - c_rig * F) * v_bracket_factor(h, b))
    E = np.array([np.median(v) if v else np.nan for v in vals])
    return E, np.array([len(v) for v in vals])


def bumper_modulus(t) -> np.ndarray:
    """The polymer's effective modulus after ``t`` s in water (:data:`BUMPER_MODULUS`), MPa.

    Log-linear interpolation of the committed medians; held constant outside their times.

    Parameters
    ----------
    t : float or (n,) float, s

    Returns
    -------
    float or (n,) float, MPa
    """
    ts, E = (np.asarray(v, float) for v in BUMPER_MODULUS[:2])
    return np.exp(np.interp(t, ts, np.log(E)))


def dry_bumper_modulus() -> float:
    """The polymer's dry modulus, MPa (the median of :func:`dry_modulus`, committed)."""
    return float(BUMPER_MODULUS[2])
