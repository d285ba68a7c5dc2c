"""Tolerances: the slacks, thresholds and floors under which values count as equal.

``tol`` (trimesh's habit) is imported by most modules as ``from pysolver.params import tol as
TOL``.  Settings that are not tolerances live with their topic: Newton iteration caps and
line-search constants in :mod:`pysolver.params.simulation`, drawing floors in
:mod:`pysolver.params.report`.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Tolerances:
    """Every geometric and numerical tolerance, named (trimesh's ``tol`` habit).

    A tolerance is a slack, a threshold or a floor under which two values count as equal
    (or a value as zero); settings that are not (iteration caps, step limits, line-search
    constants, drawing floors) live with their topic (:class:`NewtonSettings`,
    :class:`Pictures`, ...).  Source: morphshell's choices, set from the round-off of double
    precision or the accuracy a step needs, unless a field says otherwise; ``newton_grad`` is
    tighter than the reference simulator's 1e-3 (``simulator.md`` §1), so that the
    completion times do not depend on where the Newton iteration stops.

    Attributes
    ----------
    merge : float, mm
        Distance under which two points are the same point.
    stl_bbox : float, mm
        Allowed bounding-box difference between an STL and its table.
    newton_grad : float, N
        Newton convergence: infinity norm of the reduced gradient (forces in N,
        torques in N mm scaled by 1/base_r so both are forces).
    facet : float, mm
        Largest distance between a faceted circle and the true circle in the SCAD parts
        (``FACET_TOL`` of ``scad/params.scad``).
    scad_cut : float, mm
        Margin by which SCAD cutting tools overshoot the faces they cut (``CUT_EPS``).
    apex_gap : float, mm
        Actuated preview only: gap between facing bracket arms (``APEX_GAP``).
    thickness : float, mm
        Slack of the bracket thickness range check (:attr:`UnitCell.thickness_min`,
        ``thickness_max``) of values read back from the tables.
    rel : float
        Slack of comparisons between derived lengths (mm) and scale factors: round-off.
    gap : float, mm
        Slack and overshoot of the flat-gap rule (min_gap) in the layout and its check.
    degenerate : float
        Relative size (of the bounding box, squared for areas) under which a triangle or a
        vector is degenerate.
    time : float, s
        Slack of time comparisons in temporal programming.
    force_rtol : float
        Relative tolerance of the force balance solved for a bracket thickness.
    same_setting : float, mm or N
        Two measured test settings (thickness, length, force) closer than this are the same.
    exact : float
        Slack of comparisons that hold exactly but for floating-point round-off (values of
        order one, or relative to a scale): a descent test, a collapsed interval, a sampled
        range end.
    tiny : float
        Positive floor that keeps a denominator or a scale from being zero.
    energy_roundoff : float
        Relative round-off of a sum of many element energies: below it, two energies are equal
        (sufficient-decrease tests of the line searches).
    energy_floor : float, N mm
        Floor of the reference energy that scales the simulator's energy-change reports.
    small_angle : float, rad
        Rotation angle under which Rodrigues' formula is replaced by its series.
    cetm_ridge, cetm_grad : float
        Diagonal ridge added to the Hessian of the CETM flattening, and the gradient norm
        (rad) above which the flattening reports it did not converge.
    cetm_stop : float, rad
        Gradient norm under which the CETM flattening's Newton iteration stops.
    membrane_grad : float, N
        Convergence of the plane membrane relaxation of temporal programming (F_mem fit and
        per-cell factors): infinity norm of the free-node gradient.  The relaxation is refused
        as not converged above ``newton_grad``.
    input_degenerate : float
        Relative doubled area (of the bounding-box diagonal squared) under which a triangle of
        an input mesh is degenerate.
    membrane_collapse : float
        Area ratio (current / rest) under which a membrane triangle is reported as collapsed
        when a simulation step diverges.
    orientation_rel : float
        Relative size (of the extent of the points) under which the sign of an orientation
        test (normals versus centroid) is undecided.
    frame_tie : float
        Difference of two directions' third moments (relative to the absolute third moment)
        under which a flat layout's frame is a tie
        (:func:`pysolver.design.stencil.remesh.flat_frame`): a mirror symmetry, above what a
        jitter of 1e-7 of the size moves (the nearest non-tie measured: 3e-5, the spiral).
    pose_rel : float
        Relative gap between two principal second moments of a surface (of the largest), or
        third moment along a principal axis (of the area times the largest principal sd
        cubed), under which its
        principal frame is undecided (a symmetry, :func:`pysolver.geometry.canonical_pose`).
    irls_rel : float
        Relative decrease of the objective under which the robust (IRLS) scan fit stops.
    rank_rtol : float
        Singular values below this fraction of the largest make a fitted design matrix rank
        deficient.
    active_set : float
        Slack under which a constraint of the constrained least squares is active.
    qp_relax : float
        Scale of the distinct relaxations that break the degeneracy of homogeneous constraint
        rows in the quadratic programme (far below its accepted violation).
    monotone_rtol, monotone_atol : float, -, N
        Relative and absolute force tolerance of the material model's monotonicity check.
    monotone_step : float, mm
        Step in thickness, bracket length and compression of that check.
    length_match : float, mm
        Largest difference between a measured bracket length and the one derived from its
        central length.
    qp_violation : float
        Constraint violation accepted by the cutting-plane quadratic programme of the
        constrained least squares (:func:`pysolver.material.polyfit.constrained_lstsq`).
    irls_eps_mm : float, mm
        Floor of the distances in the IRLS weights (1/max(d, eps)) of the robust scan fit.
    self_check_volume_rtol : float
        Largest relative volume difference fast vs OpenSCAD on a reference part (render
        self-check, auto mode).
    self_check_symdiff_rtol : float
        Largest symmetric-difference volume fast vs OpenSCAD, relative to the part volume
        (render self-check).
    """

    merge: float = 1e-6
    stl_bbox: float = 0.05
    self_check_volume_rtol: float = 1e-4
    self_check_symdiff_rtol: float = 1e-3
    newton_grad: float = 1e-6
    facet: float = 0.005
    scad_cut: float = 0.01
    apex_gap: float = 0.05
    thickness: float = 1e-6
    rel: float = 1e-9
    gap: float = 1e-6
    degenerate: float = 1e-12
    time: float = 1e-6
    force_rtol: float = 1e-9
    same_setting: float = 1e-6
    exact: float = 1e-12
    tiny: float = 1e-300
    energy_roundoff: float = 1e-13
    energy_floor: float = 1e-9
    small_angle: float = 1e-8
    cetm_ridge: float = 1e-8
    cetm_grad: float = 1e-6
    cetm_stop: float = 1e-10
    membrane_grad: float = 1e-9
    input_degenerate: float = 1e-10
    membrane_collapse: float = 1e-3
    orientation_rel: float = 1e-3
    pose_rel: float = 1e-3
    frame_tie: float = 1e-5
    irls_rel: float = 1e-10
    irls_eps_mm: float = 1e-4
    rank_rtol: float = 1e-9
    active_set: float = 1e-9
    qp_relax: float = 1e-11
    qp_violation: float = 1e-10
    monotone_rtol: float = 1e-3
    monotone_atol: float = 1e-4
    monotone_step: float = 1e-3
    length_match: float = 1e-3


tol = Tolerances()

__all__ = ["Tolerances", "tol"]
