"""Unit-cell dimensions, simulation constants and tolerances, in one place.

All lengths mm, forces N, times s, moduli MPa, angles deg unless a name says
``_rad``.  The defaults are the paper's (Supplementary Note 1, 2) and the
reference implementation's (``shared/design/pipeline.md`` §1.1, ``simulator.md``
§1); where they disagree the choice is written next to the field.

The OpenSCAD modules in ``scad/`` take the same numbers from ``scad/params.scad``, which is
generated from :class:`UnitCell`, :class:`SupportFrame` and :class:`Tolerances`
(``make scad-params``, :mod:`pysolver.render.scad_params`); a test checks it is up to date.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import asdict, dataclass
from pathlib import Path

from .errors import InputError


@dataclass(frozen=True)
class UnitCell:
    """Geometry of bases, brackets and bumpers (mm, deg).

    Attributes
    ----------
    base_r : float, mm
        Base disc radius (Ø 4 mm).
    base_th : float, mm
        Layer core thickness; also the side of the square bumper prism.
    base_p : float, mm
        Base indent: extra base height on the membrane side (0.3 mm), which
        leaves a 2 * base_p slot between opposing bumpers for the membrane.
    bracket_w : float, mm
        Bracket height (out of plane), 1 mm.
    min_gap : float, mm
        Minimal flat gap between facing bumper tips (2D scaling rule), 0.1 mm.
        The reference's json has 0.0 (stale); its examples and the paper use 0.1.
    min_bumper : float, mm
        Minimal bumper length beyond the base rim (3D scaling rule).  The paper
        says 0.3 mm, most reference examples 0.1 mm; we follow the paper: a
        longer bumper stops the bracket further from its breaking strain.
    clearance : float, mm
        Printing clearance removed from every bumper tip, 0.05 mm.
    align_r : float, mm
        Alignment hole radius (Ø 1.5 mm; the reference passes 0.75 as radius).
    marker_r, marker_depth : float, mm
        Marker-dot pocket radius and depth on the far face.
    max_cell_length : float, mm
        Longest printable unit cell (flat centre distance), 9.5 mm.
    """

    base_r: float = 2.0
    base_th: float = 2.0
    base_p: float = 0.3
    bracket_w: float = 1.0
    min_gap: float = 0.1
    min_bumper: float = 0.3
    clearance: float = 0.05
    align_r: float = 0.75
    marker_r: float = 0.3
    marker_depth: float = 0.5
    max_cell_length: float = 9.5
    alpha_margin_deg: float = 7.0
    thickness_min: float = 0.30
    thickness_max: float = 0.65

    @property
    def layer_h(self) -> float:
        """Height of one printed layer (base_th + base_p = 2.3 mm)."""
        return self.base_th + self.base_p

    @property
    def alpha_deg(self) -> float:
        """Bracket arm angle to the cell axis: asin(base_th / (2 base_r)) + 7 deg = 37 deg."""
        return math.degrees(math.asin(self.base_th / (2 * self.base_r))) + self.alpha_margin_deg

    @property
    def alpha_rad(self) -> float:
        return math.radians(self.alpha_deg)

    @property
    def bracket_offset(self) -> float:
        """l - b: central length minus bracket length, 2 base_r cos(alpha) = 3.1945 mm."""
        return 2 * self.base_r * math.cos(self.alpha_rad)

    def bracket_length(self, central_length):
        """Bracket length b (mm) of a cell of flat central length l (mm): b = l - 2 r cos(alpha)."""
        return central_length - self.bracket_offset

    def shortest_cell(self) -> float:
        """Shortest flat central length the scaling rules allow, mm: a flat cell whose
        bumpers stick out ``min_bumper`` and keep ``min_gap``, ``2 (base_r + min_bumper) +
        min_gap``."""
        return 2 * (self.base_r + self.min_bumper) + self.min_gap

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class SimConstants:
    """Physical and numerical constants of the simulator (simulator.md §1, §6, §8).

    Attributes
    ----------
    tau : float
        Membrane equibiaxial pre-stretch factor.
    mu : float, MPa
        Membrane shear modulus (incompressible neo-Hookean).
    membrane_h : float, mm
        Membrane thickness.
    kappa_s : float, N/mm^2
        Shear-resisting (cross pair) stiffness, weighted by the flat diagonal sum.
    kappa_c : float, N/mm
        Bumper contact spring stiffness (E = kappa_c/2 (L - L_c)^2; 2 * 99.9).
    eta : float
        Plastic fraction.
    dt, t_end : float, s
        Time step and end time.
    boundary_weakening : float
        Factor on the target membrane force of boundary cells (thickness design).
    """

    tau: float = 3.0
    mu: float = 0.72
    membrane_h: float = 0.5
    kappa_s: float = 0.1
    kappa_c: float = 199.8
    eta: float = 0.2
    dt: float = 0.5
    t_end: float = 120.0
    boundary_weakening: float = 0.6
    membrane_max_area: float = 5.0
    membrane_min_angle: float = 20.0


@dataclass(frozen=True)
class SupportFrame:
    """The support frame printed around each layer (``scad/support_frame.scad``), mm.

    Attributes
    ----------
    offset_in, offset_out : float, mm
        The ring lies between these offsets of the flat outline (reference: 6 and 9);
        the same values as ``FRAME_OFFSET_IN``/``FRAME_OFFSET_OUT`` of ``scad/params.scad``.
    connector_w : float, mm
        Square section of a breakaway connector (``CONNECTOR_W``).
    connector_r0 : float, mm
        Connectors start this far from the base centre, inside the base (``CONNECTOR_R0``).
    spacing : float, mm
        A boundary base gets a connector only if no connected base lies within this flat
        distance (greedy in base order, as the reference).
    connector_max_reach : float, mm
        Longest connector beyond its base's boundary edge.  Each connector ends in the
        middle of the ring along its own direction; where the ring is farther (deep in a
        notch of the outline) or the direction crosses the shell again, the base gets no
        connector and the next boundary base is tried.
    step : float, mm
        Sampling step along a connector when its end in the ring is searched.
    hole_margin : float, mm
        Holes of the ring's inner offset (which would leave loose ring islands) are filled
        grown by this much, to overlap the inner offset whatever its faceting.
    circle_segments : int
        Segments per full circle of the round offsets computed in Python (manifold3d).
    """

    offset_in: float = 6.0
    offset_out: float = 9.0
    connector_w: float = 0.5
    connector_r0: float = 1.0
    spacing: float = 30.0
    connector_max_reach: float = 15.0
    step: float = 0.02
    hole_margin: float = 0.1
    circle_segments: int = 256


@dataclass(frozen=True)
class Tolerances:
    """Every geometric and solver tolerance, named (trimesh's ``tol`` habit).

    Attributes
    ----------
    merge : float, mm
        Distance under which two points are the same point.
    stl_bbox : float, mm
        Allowed bounding-box difference between an STL and its table.
    newton_grad : float, N
        Newton convergence: infinity norm of the reduced gradient (forces in N,
        torques in N mm scaled by 1/base_r so both are forces).
    newton_max_iter_dry, newton_max_iter_wet : int
        Newton iteration caps for the dry step and the wet steps.
    newton_max_iter_rest : int
        Cap of the dry resting shape's solve (``--physics dry-rest``): the shell settles
        on a frictionless table by a slow, nearly rigid roll (330 iterations on the
        printed spiral).
    facet : float, mm
        Largest distance between a faceted circle and the true circle in the SCAD parts
        (``FACET_TOL`` of ``scad/params.scad``).
    scad_cut : float, mm
        Margin by which SCAD cutting tools overshoot the faces they cut (``CUT_EPS``).
    apex_gap : float, mm
        Actuated preview only: gap between facing bracket arms (``APEX_GAP``).
    thickness : float, mm
        Slack of the bracket thickness range check (values written to 6 decimals).
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
    contact_ccd_safety : float
        Fraction of the collision-free step (continuous collision detection) a Newton step
        may take with contact barriers on (IPC's 0.8).
    contact_skin_mm : float, mm
        Verlet skin of the contact broad phase (``sim.model.contact``): the list of non-neighbouring
        base pairs is built ``2 skin`` wider than needed and reused until some base centre has
        moved ``skin`` from where it was built.
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
    armijo_c1 : float
        Sufficient-decrease constant of the line searches (Nocedal & Wright's ``c1``).
    small_angle : float, rad
        Rotation angle under which Rodrigues' formula is replaced by its series.
    newton_shift_min, newton_shift_floor : float
        Smallest regularisation shift of a Newton solve (relative to the mean scaled Hessian
        diagonal), and the floor of the shift a Newton iteration starts from.
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
    irls_rel : float
        Relative decrease of the objective under which the robust (IRLS) scan fit stops.
    colour_floor_mm : float, mm
        Smallest upper limit of a colour scale of distances (a perfect result is not drawn
        with an arbitrary scale).
    rate_floor : float, mm/min
        Floor of a measured rate drawn on a logarithmic axis.
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
    newton_shift_max : float
        Largest adaptive regularisation shift of a Newton solve (relative, as
        ``newton_shift_min``) before the convexified Hessian is tried.
    newton_psd_shifts : tuple of float
        Shifts tried, after ``newton_shift_min``, with the convexified (positive
        semi-definite) Hessian of a Newton solve.
    newton_max_rot_rad : float, rad
        Largest rotation of a base per Newton iteration.
    newton_max_step_mm : float, mm
        Largest move of a base centre or membrane vertex per Newton iteration.
    wolfe_c2 : float
        Curvature constant of the strong Wolfe line search (Nocedal & Wright's ``c2``).
    qp_violation : float
        Constraint violation accepted by the cutting-plane quadratic programme of the
        constrained least squares (:func:`pysolver.material.polyfit.constrained_lstsq`).
    settle_mm : float, mm
        Early stop of a simulation: largest base-centre or vertex move in a step of a
        settled shell (``SimSettings.settle_mm``).
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
    newton_max_iter_dry: int = 200
    newton_max_iter_wet: int = 100
    newton_max_iter_rest: int = 1000
    newton_max_rot_rad: float = 0.3
    newton_max_step_mm: float = 2.0
    line_search_halvings: int = 30
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
    contact_ccd_safety: float = 0.8
    contact_skin_mm: float = 1.0
    settle_mm: float = 1e-4
    exact: float = 1e-12
    tiny: float = 1e-300
    energy_roundoff: float = 1e-13
    energy_floor: float = 1e-9
    armijo_c1: float = 1e-4
    wolfe_c2: float = 0.9
    small_angle: float = 1e-8
    newton_shift_min: float = 1e-8
    newton_shift_floor: float = 1e-6
    newton_shift_max: float = 1.0
    newton_psd_shifts: tuple = (1e-4, 1e-2, 1.0)
    cetm_ridge: float = 1e-8
    cetm_grad: float = 1e-6
    cetm_stop: float = 1e-10
    membrane_grad: float = 1e-9
    input_degenerate: float = 1e-10
    membrane_collapse: float = 1e-3
    orientation_rel: float = 1e-3
    irls_rel: float = 1e-10
    irls_eps_mm: float = 1e-4
    colour_floor_mm: float = 1e-3
    rate_floor: float = 1e-3
    rank_rtol: float = 1e-9
    active_set: float = 1e-9
    qp_relax: float = 1e-11
    qp_violation: float = 1e-10
    monotone_rtol: float = 1e-3
    monotone_atol: float = 1e-4
    monotone_step: float = 1e-3
    length_match: float = 1e-3


@dataclass(frozen=True)
class Limits:
    """Upper bounds of the size and count options, so that a typo (``--vertices 10000000``)
    is refused at once instead of running for hours.

    Attributes
    ----------
    max_vertices : int
        Stencil vertices (``--vertices``); the paper's largest shell has 330.
    max_refine : int
        Timing refinement rounds (``--refine``), each one simulation.
    max_jobs : int
        Parallel render processes (``--jobs``).
    max_t_end : float, s
        Simulated time in water (``--t-end``).
    min_dt : float, s
        Smallest simulation time step (``--dt``).
    max_steps : int
        Simulation steps, ``t_end / dt``.
    max_scale : float
        Input scale factor (``--scale``).
    size_mm : (float, float), mm
        Range of ``--size`` (largest bounding-box extent of the scaled target); the same
        band as the unitless-size check of :mod:`pysolver.design.mesh_input` (bounding-box
        diagonal 20-2000 mm) applied to one extent.
    min_bumper_mm : (float, float), mm
        Range of ``--min-bumper`` (bumper length beyond the base rim, 3D scaling rule).
        Longer than 2 mm, the bumpers would reach past the bracket's roots.
    min_gap_mm : (float, float), mm
        Range of ``--min-gap`` (flat gap between facing bumper tips, 2D scaling rule).
    max_time_file_bytes : int, bytes
        Largest ``--time-file`` or ``--thickness-file`` read (one row per vertex or unit cell:
        millions of them).
    max_cell_length_mm : float, mm
        Upper bound of ``--max-cell-length`` (flat central length of a unit cell): the
        bracket model's last measured length (l = 9.0 mm, ``bracket_length_mm`` grid end
        5.8055 + 3.1945) plus two steps of its 0.25 mm length grid, which is how far the
        clamped model is used today (cells beyond 9.0 mm are warned about).  The lower
        bound is the shortest cell the scaling rules allow, ``2 (base_r + min_bumper) +
        min_gap`` (:meth:`UnitCell.shortest_cell`).
    model_max_central_length_mm : float, mm
        The bracket model's last measured central length (its grid ends at b = 5.8055 mm);
        longer cells (up to ``max_cell_length_mm``) are warned about.
    measured_x_mm, measured_force_N, measured_h_mm : (float, float)
        Plausible peak displacement (mm), peak force (N) and thickness (mm) of a bracket test
        file (:mod:`pysolver.material.measurements`); outside, the column is in another unit.
    measured_duration_s : (float, float), s
        Shortest plausible wet and dry test (they last about 2 min and 7 s).
    render_part_timeout_s : float, s
        A fast-renderer worker stuck this long on one part is killed and the part reported
        failed.
    render_startup_timeout_s : float, s
        Time a new fast-renderer worker may take to import the evaluator before it counts
        as dead.
    probe_timeout_s : float, s
        Time the off-screen rendering probe of the report's pictures may take.
    """

    max_vertices: int = 5000
    max_refine: int = 10
    max_jobs: int = 256
    max_t_end: float = 3600.0
    min_dt: float = 0.01
    max_steps: int = 20000
    max_scale: float = 1e6
    size_mm: tuple = (20.0, 2000.0)
    min_bumper_mm: tuple = (0.0, 2.0)
    min_gap_mm: tuple = (0.0, 2.0)
    max_cell_length_mm: float = 9.5
    model_max_central_length_mm: float = 9.0
    measured_x_mm: tuple = (0.05, 100.0)
    measured_force_N: tuple = (0.05, 1000.0)
    measured_h_mm: tuple = (0.05, 5.0)
    measured_duration_s: tuple = (3.0, 1.0)
    max_time_file_bytes: int = 64 * 1024 * 1024
    render_part_timeout_s: float = 300.0
    render_startup_timeout_s: float = 120.0
    probe_timeout_s: float = 120.0


LIMITS = Limits()


@dataclass(frozen=True)
class ReportThresholds:
    """Limits of the report's verdict (justified in ``docs/report.md``); imported by
    :mod:`sim.report.report` as ``Thresholds``.

    Attributes
    ----------
    shape_rms_warn_pct, shape_rms_fail_pct : float, %
        RMS distance of the aligned final base centres to the target centres,
        in % of the target size (bounding-box diagonal of the target centres).
    shape_max_warn_pct : float, %
        Largest single base distance, % of the target size (a local defect).
    normal_warn_deg, normal_fail_deg : float, deg
        RMS angle between the aligned final base normals (flat +z of each base)
        and the target face normals (global orientation of the layers).
    fold_rms_warn_deg : float, deg
        RMS error of the signed fold angle per unit cell (angle between the two
        base normals, + when folding toward the top layer; ``cells.csv``
        ``fold_angle_deg``).  Alignment-free: measures the local bending.
    fold_flip_fail_fraction : float
        Fraction of the folded cells (target ``|fold| >= fold_min_deg``) whose
        simulated fold has the opposite sign, above which the shell is bent
        the wrong way: FAIL.  Any flipped folded cell is a WARN.
    fold_min_deg : float, deg
    timing_rms_warn_s : float, s
        RMS of (simulated completion - t*) over the cells that complete.
    spearman_warn : float
        Rank correlation of simulated completion vs t* below this: the order of
        morphing is not the programmed one.  Only checked when the programmed
        t* spread (std) is at least ``timing_spread_min_s``.
    timing_spread_min_s : float, s
    incomplete_fail_fraction : float
        Fraction of unit cells (with t* <= the simulated end time) that never
        complete above which the morph has not happened: FAIL.  Any such cell
        is a WARN.
    collision_depth_mm : float, mm
        Penetration deeper than this counts as a collision (base/base and
        membrane/base).
    membrane_collision_fail : bool
        Membrane-through-base collisions are FAIL (True) or WARN (False).
    residual_fail_N : float, N
        A non-converged step whose final residual is above this is FAIL; below
        it, WARN.
    listed_cells : int
        Longest list of cell (or frame) ids a report or refinement record names.
    """

    shape_rms_warn_pct: float = 2.0
    shape_rms_fail_pct: float = 5.0
    shape_max_warn_pct: float = 10.0
    normal_warn_deg: float = 15.0
    normal_fail_deg: float = 45.0
    fold_rms_warn_deg: float = 5.0
    fold_flip_fail_fraction: float = 0.25
    fold_min_deg: float = 1.0
    timing_rms_warn_s: float = 10.0
    spearman_warn: float = 0.5
    timing_spread_min_s: float = 2.0
    incomplete_fail_fraction: float = 0.5
    collision_depth_mm: float = 0.1
    membrane_collision_fail: bool = False
    residual_fail_N: float = 1e-3
    listed_cells: int = 50

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.type in ("float", float) and not (isinstance(v, (int, float))
                                                    and math.isfinite(v) and v >= 0):
                raise InputError(f"Thresholds.{f.name} = {v!r}: must be a finite number >= 0",
                                 fix="pass a non-negative number")
        if not (isinstance(self.listed_cells, int) and self.listed_cells >= 1):
            raise InputError(f"Thresholds.listed_cells = {self.listed_cells!r}: must be a "
                             "whole number >= 1", fix="pass how many cell ids a list names")
        if self.shape_rms_warn_pct > self.shape_rms_fail_pct:
            raise InputError("Thresholds: shape_rms_warn_pct > shape_rms_fail_pct",
                             fix="the WARN limit must not exceed the FAIL limit")
        if self.normal_warn_deg > self.normal_fail_deg:
            raise InputError("Thresholds: normal_warn_deg > normal_fail_deg",
                             fix="the WARN limit must not exceed the FAIL limit")

    @classmethod
    def coerce(cls, value) -> ReportThresholds:
        """``None`` -> defaults; a mapping -> defaults updated by it; a Thresholds as is."""
        if value is None:
            return cls()
        if isinstance(value, cls):
            return value
        if isinstance(value, dict):
            names = {f.name for f in dataclasses.fields(cls)}
            bad = sorted(set(value) - names)
            if bad:
                raise InputError(f"unknown threshold(s) {bad}",
                                 fix=f"use some of {sorted(names)}")
            return cls(**value)
        raise InputError(f"thresholds must be a Thresholds or a dict, got {type(value).__name__}")


REPORT = ReportThresholds()


@dataclass(frozen=True)
class ModelLimits:
    """Ranges, floors, fixed fractions and mesh sizes of the design checks, the material and
    membrane models, the temporal programming and the tolerance analysis.

    Attributes
    ----------
    membrane_b0_mm : (float, float), mm
        Range of the flat bracket length b0 of :func:`pysolver.fitting.cell_membrane.
        membrane_traction` (its unit-cell membrane patch).
    membrane_d_max_fraction : float
        Largest contraction d of that patch, as a fraction of b0 (exclusive).
    near_limit_fraction : float
        A cell whose flat central length is above this fraction of ``max_cell_length`` (and
        not above it) is warned about as near the limit (:mod:`pysolver.design.checks`).
    max_clamped_fraction : float
        Largest fraction of cells whose thickness is clamped to the printable range for a
        temporal program to be feasible.
    bisection_steps : int
        Bisection steps of the thickness and completion-time solves of temporal programming.
    refine_damping : float
        Damping of the timing corrections of the refinement from the simulation.
    refine_open_layer_mm : float, mm
        A layer still open at the end of a simulation, in a cell that never completes,
        is made this much thinner by the next refinement round (``build._thin_open_layers``).
    refine_extra_rounds : int
        Rounds the refinement adds after the ones asked for while its best round still
        has cells that never complete (each one more simulation).
    relaxation_min_samples : int
        Fewest samples of the hold step of a stress-relaxation test.
    relaxation_weight_floor_s : float, s
        Floor of the time in the 1/sqrt(t) weights of the Prony fit of stress relaxation
        (the test records every 4 s).
    tolerance_thickness_floor_mm : float, mm
        Smallest bracket thickness drawn by the tolerance analysis (printed thickness).
    tolerance_modulus_floor : float
        Smallest membrane modulus factor drawn by the tolerance analysis.
    membrane_fit_max_area : float, mm^2
        Largest flat triangle of the membrane patches of the membrane-model fit (converged
        to ~0.3 %; the simulator uses ``SimConstants.membrane_max_area``).
    membrane_factor_max_area : float, mm^2
        Largest flat triangle of the membrane mesh of a design's own stencil (per-cell
        membrane factors).
    membrane_contraction_min : float
        Smallest uniform contraction (current / flat size) of the stencil estimated from the
        cells' closing distances for the per-cell membrane factors.
    """

    membrane_b0_mm: tuple = (0.3, 7.0)
    membrane_d_max_fraction: float = 0.95
    near_limit_fraction: float = 0.95
    max_clamped_fraction: float = 0.5
    bisection_steps: int = 50
    refine_damping: float = 0.8
    refine_open_layer_mm: float = 0.1
    refine_extra_rounds: int = 2
    relaxation_min_samples: int = 10
    relaxation_weight_floor_s: float = 4.0
    tolerance_thickness_floor_mm: float = 0.05
    tolerance_modulus_floor: float = 0.05
    membrane_fit_max_area: float = 0.5
    membrane_factor_max_area: float = 1.0
    membrane_contraction_min: float = 0.5


@dataclass(frozen=True)
class StencilSearch:
    """Settings of the stencil generation (:mod:`pysolver.design.remesh`,
    :mod:`pysolver.design.stencil_opt`).

    Attributes
    ----------
    dense_faces : int
        User meshes are resampled to about this many well-shaped faces before flattening.
    min_boundary_points : int
        Fewest points on the stencil's rim.
    lloyd_iterations : int
        Weighted Lloyd iterations of the CVT in the conformal plane.
    relax_iterations : int
        Spring relaxation iterations (Persson and Strang's scheme) after the CVT.
    relax_retriangulate : int
        Delaunay re-triangulation every this many relaxation iterations.
    relax_fscale, relax_step : float
        Rest length over mean length of the repulsive springs (1.2 as in Persson and
        Strang) and the explicit step size.
    grading : float
        Target spacing in 3D ``~ exp(u)^(-grading)`` (u = conformal log-scale):
        0 = uniform in 3D (isotropic and uniform on the target), 1 = uniform in the plane.
        The default 0.5 is the reference's own weighting (``pipeline.md`` §2.2); measured on
        the paper's cover (``--size 106 --min-bumper 0.1``), it clamps 12.7 % of the cells of
        a constant 60 s landscape and 22 % of the reference landscape, against 27 % and
        35.5 % for 1: the 3D cell lengths, hence the bumpers' contact lengths that set each
        cell's time range, vary less (coefficient of variation 0.22 against 0.26).
    rim_insets : tuple of float
        Insets of the stencil boundary from the target's boundary, as fractions of the edge
        of the smallest regular cell the min-bumper rule allows (``sqrt(3) 2 (base_r +
        min_bumper)``, 7.3-8 mm), tried in order (0 = the stencil reaches the rim).  A
        CVT's outer sites lie about 0.3-0.5 spacing inside its domain; the reference's
        stencils cover 80-88 % of their targets for that reason.  The inset removes the
        rim's sharpest features (the stand's notches), where cells fold most.
    opt_sharpness : float
        Log-sum-exp sharpness of the smoothed maxima in the stencil optimisation.
    opt_s3_weight : float
        Weight of log(3D scaling) beside log(longest flat cell) in the objective.  At 0 the
        optimisation shortens the longest cell mostly by enlarging the smallest target
        cells, which lowers the 3D scaling, and the count search then restores the size
        with more vertices (the stand: 502 bases at 9.17 mm, the reference 396 at 9.63 mm).
        -0.7 credits most of that back, so the optimisation improves the longest cell per
        unit of scaling instead; measured (the count search as a whole): the stand 433 bases
        at 9.45 mm, cover (0.1 mm bumper) 589 at 8.30 mm, against 502 and 611 at 0; -0.5
        left the stand at 502, -1 lets the optimisation shrink cells (a 3D scaling of 1.5 at
        the stand's count).
    opt_min_angle_deg, opt_max_angle_deg, opt_angle_weight : float
        Flat corner angles outside this range (deg) are penalised with this weight (per
        rad^2): a base's disc (r 2 mm) must not reach across its triangle's edges (a
        30-30-120 triangle puts its centroid 1.2 mm from its long edge per 12 mm).
    opt_centroid_edge_mm : float, mm
        Smallest distance from a base centre (flat centroid) to its triangle's edges in the
        scaled layout: a base's disc and bracket roots (r 2 mm) stay inside the membrane
        region the simulator's and the F_mem correction's meshes give each base (the
        reference's stencils keep >= 2.6 mm).
    opt_clearance_weight : float
        Weight of the squared log shortfall of a base centre's clearance.
    opt_clearance_slack : float
        Log shortfall of the clearance (2 %) a round may leave and still be kept.
    opt_tiny : float
        Floor of the arguments of the barrier's and penalties' logarithms, and the guard
        added under the square root of the half fold's tangent (finite gradient when flat).
    opt_rounds, opt_iterations : int
        Outer rounds (re-lifting onto the target) and L-BFGS iterations per round.
    opt_barrier : float
        Weight of the log barrier that keeps flat triangles positively oriented.
    opt_timing_weight : float
        Weight of the timing misfit (:func:`pysolver.design.stencil_opt.timing_misfit`) in
        the stencil optimisation, when a time landscape is known (0 = off).
    timing_fastest, timing_slowest : tuple of float
        ``(c, a, e, k)`` of the estimates ``log t ~ c + a log b0 + e log x + k [boundary]``
        (t in s) of the fastest and slowest completion time a cell can reach (brackets of
        ``thickness_min`` and ``thickness_max``) from its bracket length b0 (mm),
        compression x (mm) and whether it lies on the rim.  Least squares on the times
        temporal programming computed for 5448 and 3427 cells of six cover designs (the
        reference's stencil and morphshell's) and the stand: residual SD 0.22 and 0.27 in
        log t.  They only steer the stencil optimisation; temporal programming computes
        each cell's times from the material and membrane models.
    timing_margin : float
        The misfit narrows each cell's estimated range by this much (log time) at both ends:
        the estimates' own error is 0.22-0.27.
    opt_timing_iterations : int
        L-BFGS iterations per round when the timing term is on (it needs more than the
        longest cell alone).
    opt_cap_weight : float
        With the timing term, weight (per log^2) of the penalty that keeps the exact longest
        flat cell under ``max_cell_length - margin``: without it the timing term can trade
        the count search's footing away (measured on cover: 3D scaling 0.82 at 418 bases).
    seeds : int
        Seeds tried at the chosen vertex count when none is given and the first seed
        leaves less than ``margin`` below the limit.
    count_start : float
        First vertex count of the search over the paper's estimate ``0.38 A / 7^2``
        (measured: the counts found are 1.4-1.7 x the estimate on cover, stand, petal,
        spiral).
    count_steps : int
        Secant steps of the vertex count toward a 3D scaling of 1.
    count_tolerance : float
        |log scale3d| under which the secant search stops.
    count_secant_min : float
        Smallest difference of log vertex counts of the last two trials over which the
        secant slope is taken (else the uniform-mesh slope 1/2).
    dense_min_angle_deg : float, deg
        An input mesh whose smallest triangle angle is below this is resampled (dense
        remeshing) before flattening.
    dense_min_faces : int
        An input mesh with fewer faces than this is resampled before flattening.
    remesh_surface_dist : float
        Largest distance of the isotropic remeshing's surface from the input, relative to
        the target edge length.
    candidates : tuple of float
        Relative vertex counts tried around the secant result (the other seeds are tried at
        the best count).
    margin : float, mm
        Preferred distance of the longest flat cell below the limit.
    opt_pin_weight : float
        Weight (per log^2) of the penalty that holds the exact 3D scaling at 1 when the chosen
        stencil is optimised once more for its longest flat cell per unit of scaling
        (:func:`pysolver.design.remesh.remesh_surface`; 0 = no second pass): the count
        search's scaling lands within a few per cent of 1 (its tolerance, and the seeds'
        noise), this pass brings it within 0.5 % (30 left 1-4 %).
    min_area_covered : float
        When the stencil the first rim inset gives covers less than this fraction of the
        target's area (3D area of the stencil over the target's), the search also tries the
        stencil without an inset and takes it only if it prints at least as well (its longest
        flat cell within ``max_cell_length - margin``, or within the limit when the inset
        stencil is not within the margin either); otherwise the inset stencil stays.  On a
        narrow target the inset removes whole rows of cells and leaves short rim cells that
        never finish.  Measured (inset stencils of the default search): the spiral (32 mm
        wide) 72 %, and with the inset 2.7 % RMS and 13 rim cells that never finish in the
        simulation; without it (8.81 mm longest cell before the last pass) 0.63 % and 3.
        ``petal:size=0.7`` 65 %, but without the inset its longest cell is 9.71 mm (> 9.5),
        so the inset stays.  Above the threshold: petal 77 %, saddle 81 %, dome 82 %, the
        stand (``--size 171``) 85 %, the cover (``--size 106 --min-bumper 0.1``) 88 %; the
        reference's stencils cover 80-88 %.
    remove_flaps : bool
        Merge the two triangles of a rim vertex that has only two (a flap:
        :func:`pysolver.design.remesh.remove_flaps`).  Its two rim bases, joined by one
        cell and hanging from the rest by one cell each, turn in plane in water and lock
        with their cells closed at one end.  Measured on the spiral: with flaps, 3 such
        cells never finish, whatever the refinement does; without them, none.
    flap_min_angle_deg : float, deg
        A flap is kept where the merged triangle would have a smaller angle (its inner
        vertex near the chord: a base would reach across the triangle's edge).
    trade_counts : tuple of float
        With a time landscape the user gave (``--time``, ``--time-file``), relative vertex
        counts below the chosen one also tried: larger cells are faster, and a landscape
        that asks for early times may clamp fewer cells on them
        (:func:`pysolver.design.stencil_opt.estimated_clamping`).  The trade shrinks the
        shell (its 3D scaling falls below 1), so it is taken only as below and reported.
        Measured on cover with the reference's landscape (``--size 106 --min-bumper 0.1
        --time-file``): the search's 359 vertices (scaling 0.997) clamp 16.1 % of the cells
        when programmed; the trade takes 309 (seed 1, scaling 0.935: the shell 6.5 %
        smaller), 12.5 %.  The estimate ranks stencils but scatters by seed (309 with seed
        0: scaling 1.06, ~37 %), hence both seeds.
    trade_min_scale3d : float
        Smallest 3D scaling a traded stencil may have (the shell at least this fraction of
        the requested size).
    trade_gain : float
        Smallest drop of the estimated clamped fraction that pays for the smaller shell.
    timing_grading : float
        With a landscape the user gave, the stencil's 3D spacing follows
        ``(t / t_mean)^(-timing_grading)`` besides ``grading`` (:func:`pysolver.design.remesh.
        time_spacing_log`): smaller, slower cells where the landscape asks for late times.
        Measured on cover with the reference's landscape (``--size 106 --min-bumper 0.1``):
        0 clamps 16.1 % of the cells (12.5 % with a 6.5 % smaller shell, the trade); 0.25
        8.4 % (522 bases, scaling 0.951, longest flat cell 9.11 mm); 0.3 ends at a 3D
        scaling of 0.875 (the longest flat cell binds); 0.35 and 0.5 leave no printable
        stencil (the spacing jumps at the petals' borders).  A graded
        search that is not printable or scales below ``trade_min_scale3d`` is redone
        without the grading (``remesh.timing_grading``).
    """

    dense_faces: int = 6000
    min_boundary_points: int = 6
    lloyd_iterations: int = 40
    relax_iterations: int = 100
    relax_retriangulate: int = 5
    relax_fscale: float = 1.2
    relax_step: float = 0.2
    grading: float = 0.5
    rim_insets: tuple = (0.5, 0.0)
    opt_sharpness: float = 60.0
    opt_s3_weight: float = -0.7
    opt_min_angle_deg: float = 30.0
    opt_max_angle_deg: float = 90.0
    opt_centroid_edge_mm: float = 2.3
    opt_angle_weight: float = 100.0
    opt_clearance_weight: float = 1000.0
    opt_clearance_slack: float = 0.02
    opt_tiny: float = 1e-30
    opt_rounds: int = 2
    opt_iterations: int = 50
    opt_barrier: float = 1e-3
    opt_timing_weight: float = 200.0
    timing_fastest: tuple = (6.385, -2.919, 0.776, 0.546)
    timing_slowest: tuple = (6.996, -2.15, 1.224, 0.032)
    timing_margin: float = 0.4
    opt_cap_weight: float = 1000.0
    opt_timing_iterations: int = 100
    seeds: int = 2
    count_start: float = 1.5
    count_steps: int = 4
    count_tolerance: float = 0.05
    count_secant_min: float = 1e-9
    dense_min_angle_deg: float = 15.0
    dense_min_faces: int = 2000
    remesh_surface_dist: float = 0.05
    candidates: tuple = ()
    margin: float = 0.3
    opt_pin_weight: float = 100.0
    min_area_covered: float = 0.75
    remove_flaps: bool = True
    flap_min_angle_deg: float = 30.0
    trade_counts: tuple = (0.93, 0.86)
    trade_min_scale3d: float = 0.92
    trade_gain: float = 0.03
    timing_grading: float = 0.25


STENCIL = StencilSearch()

REFERENCE_MIN_BUMPER_MM = 0.1
"""The minimal bumper of most of the reference's examples (the paper says 0.3 mm), offered as
a measured alternative when a target cannot be printed."""

DEFAULT_REFINE = 1
"""Rounds of timing refinement from the simulation, the one default of ``morphshell build``,
``make`` and :func:`pysolver.build.build`."""

@dataclass(frozen=True)
class Uncertainty:
    """Default fabrication and material uncertainty of ``morphshell tolerance``.

    Every sample of the Monte Carlo analysis (:mod:`pysolver.tolerance`) draws each factor below
    independently; a standard deviation of 0 switches a factor off.

    Attributes
    ----------
    thickness_sd : float, mm
        Per-bracket printed thickness, normal around the programmed value (FDM prints
        bracket thickness within about +-0.02 mm).  One draw per cell and layer.
    stretch_mean, stretch_sd : float
        Membrane pre-stretch factor tau, normal (set by hand, "near 3").
    modulus_rel_sd : float
        Relative standard deviation of the membrane shear modulus mu (+-10 %).
    material_sd : float or None
        Standard deviation of the natural log of the bracket compliance factor (the fitted
        bracket is ``s`` times as compliant: ``F_s(x) = F(x / s)``), one draw per sample.
        ``None``: derived from the wet fit residuals of the material model
        (:func:`pysolver.tolerance.material_scatter`).
    relaxation : bool
        Also draw a membrane stress-relaxation factor from the measured curve
        (``data/material-measurements/rubber_stress_relaxation.csv``, SI Fig. 10).
    relaxation_window_s : (float, float), s
        Time between stretching the membrane and the hot-water bath, log-uniform in this
        window (10 min .. 24 h; after about 1.5 h the curve hardly moves).
    """

    thickness_sd: float = 0.02
    stretch_mean: float = 3.0
    stretch_sd: float = 0.1
    modulus_rel_sd: float = 0.10
    material_sd: float | None = None
    relaxation: bool = False
    relaxation_window_s: tuple = (600.0, 86400.0)

    MAX_MODULUS_REL_SD = 0.3
    """Largest accepted ``modulus_rel_sd`` (30 %: a wider normal draws non-positive moduli)."""
    MAX_STRETCH_SD_FRACTION = 0.25
    """Largest accepted ``stretch_sd``, as a fraction of ``stretch_mean - 1`` (the drawn
    stretch stays well above 1)."""


@dataclass(frozen=True)
class ToleranceRun:
    """Run settings of ``morphshell tolerance`` and ``morphshell sweep``.

    Attributes
    ----------
    samples : int
        Monte Carlo samples (``--samples``, ``make tolerance SAMPLES=``).
    max_samples : int
        Upper bound of ``--samples`` (a typo is refused, not run for days).
    seed : int
        Seed of the sample draws (fixed: a rerun gives the same numbers).
    time_tol_s : float, s
        A cell is *on time* when it completes within this of its programmed t* (the
        report's timing RMS warning limit).
    sensitivity_samples : int
        One-at-a-time runs per uncertainty factor for the sensitivity table (0 = off).
    material_robust_k : float
        MAD-to-standard-deviation factor of a normal distribution (1.4826), used to turn
        the per-curve fit residuals into :attr:`Uncertainty.material_sd` robustly.
    max_variants : int
        Upper bound of the variants of one sweep.
    progress_every_s : float, s
        Shortest interval between two progress lines of a distributed run.
    """

    samples: int = 64
    max_samples: int = 10000
    seed: int = 0
    time_tol_s: float = 10.0
    sensitivity_samples: int = 8
    material_robust_k: float = 1.4826
    max_variants: int = 2000
    progress_every_s: float = 2.0


@dataclass(frozen=True)
class ModelFileRules:
    """Rules of the model-file validator (:mod:`pysolver.material.validate`).

    The bracket (material) model and the membrane model are read from JSON files that a user
    can write or edit; every rule below is checked before any stage runs.

    Attributes
    ----------
    max_bytes : int, bytes
        Largest model file read (the committed bracket model is ~0.3 MB).
    format_version : int
        Newest bracket-model ``format_version`` this code reads.
    grid_min_nodes : int
        Nodes per grid axis at least (trilinear interpolation needs a cell).
    stiffness_min : float, N/mm
        The stiffness at zero compression, ``c1 = F'(0)``, must exceed this at every node.
    stiffness_tol : float, N/mm
        Negative ``F'(x)`` allowed on ``[0, b]`` at a node (round-off of the fit's
        constraints; the committed model reaches -8e-9 N/mm).
    compressions : int
        Compressions ``x = b/n, 2b/n, .., b`` checked at each grid node.
    force_rise_tol : float
        Forces must fall with time in water: at every node and compression, ``F(t)`` may rise
        above its minimum over earlier times by at most this fraction of ``F(t=0)`` (the
        committed model rises by up to 4.9 %, a fit without one specimen by 5.5 %, both at
        b = 0.81 mm, below the measured lengths).
    softening_median_max : float
        The brackets must soften in water: the median over nodes and compressions of
        ``F(t_last) / F(t=0)`` must not exceed this (committed model: 0.056).
    plastic_fraction_max : float
        Upper bound (exclusive) of a stored plastic fraction ``eta`` (lower bound 0).
    membrane_b_range_mm : (float, float), mm
        Flat bracket lengths at which the membrane force is checked (the bracket model's grid
        starts at 0.81 mm; the longest cell, 9.5 mm, has b = 6.31 mm).
    membrane_d_fraction : float
        Shortenings ``d`` in ``[0, membrane_d_fraction * b]`` are checked: the membrane force
        must stay positive and must not grow as the cell shortens (the pre-stretch relaxes).
    membrane_samples : int
        Samples per axis of that check.
    boundary_factor_range : (float, float)
        Allowed ``boundary_factor`` (exclusive lower, inclusive upper bound).
    """

    max_bytes: int = 64 * 1024 * 1024
    format_version: int = 1
    grid_min_nodes: int = 2
    stiffness_min: float = 0.0
    stiffness_tol: float = 1e-6
    compressions: int = 20
    force_rise_tol: float = 0.10
    softening_median_max: float = 0.5
    plastic_fraction_max: float = 1.0
    membrane_b_range_mm: tuple = (0.8, 6.4)
    membrane_d_fraction: float = 0.7
    membrane_samples: int = 12
    boundary_factor_range: tuple = (0.0, 1.0)


@dataclass(frozen=True)
class PhysicsOptions:
    """Physics beyond the reference simulator (issues #18, #32), each switchable.

    With every switch off (:data:`PHYSICS_OFF`, ``--physics none``) the simulation is the
    reference model, bit for bit.  The simulator's default is :data:`PHYSICS_DEFAULT`, the
    set chosen against the 3D scan of a printed shell (``docs/physics.md``, "Calibration on a
    printed shell").  Units: mm, N, s, MPa, deg C; densities in g/cm^3 (= 1e-9 t/mm^3;
    weights are ``rho * 1e-9 * V * g`` in N for ``V`` in mm^3 and ``g`` in mm/s^2).  What
    each effect does and what it changes: ``docs/physics.md``.

    Attributes
    ----------
    relaxation : bool
        Membrane stress relaxation (SI Note 5 step 2, SI Fig. 10): the membrane modulus is
        scaled by the measured relaxation function ``g(t)`` (:data:`RELAXATION_PRONY`) of the
        time since stretching, ``stretch_to_glue_min + glue_to_water_min`` plus the time in
        water.
    stretch_to_glue_min : float, min
        Stretching the sheet to gluing the lattices (SI Note 5 steps 2-5; assumed).
    glue_to_water_min : float, min
        Gluing to immersion (steps 6-8: 5 min wait, release, cutting out; assumed).
    gravity : bool
        Weight and buoyancy in water; the shell rests on the tank floor (a plane).
    dry_rest : bool
        After the morph, the dry resting shape on a table: the brackets cool under the load
        they carry (each keeps its final force, further deformation meets the dry
        stiffness), the membrane is back at ``lab_temp_c``, full weight, contact with the
        plane.
    drying_min : float, min
        Time from taking the shell out of the water to the scan of the dry shell (SI Note 5
        step 9: "roughly 15 minutes"); only the membrane's relaxation uses it.
    print_density : float, g/cm^3
        Printed parts (Stratasys J750 photopolymers are 1.15-1.20; VeroClear 1.18).
    water_density : float, g/cm^3
        Water at 56 C.
    latex_density : float, g/cm^3
        Natural-rubber latex sheet.
    gravity_mm_s2 : float, mm/s^2
    face_down : {"bottom", "top"}
        The layer that faces the floor and the table (the flat shell lies on it).
    ground_stiffness : float, N/mm^3
        Cubic penalty of the plane contact ``E = k/3 max(0, -d)^3`` (d = height above the
        plane); 1e3 N/mm^3 lets a 1 mN point load sink by 1e-3 mm.
    ground_points : int
        Contact points per base face: the rim of each far face (radius ``base_r``).
    rim : bool
        The membrane as fabricated at the rim (SI Note 5 steps 6-7): a strip of latex
        ``rim_margin_mm`` wide around the outline, the "tiny amount of degenerated latex"
        kept when the shell is cut out.  Glue was spread on it before the sheet was released
        ("to freeze it"), so it keeps the flat shape it had when the glue set: it rests at
        the flat layout divided by ``rim_stretch`` (1 = frozen, no pre-stress) and holds
        the latex of a sheet stretched by ``tau`` (thickness ``membrane_h / tau^2``).
    rim_margin_mm : float, mm
        Width of the latex margin kept at the border (flat, as cut).
    rim_stretch : float
        Pre-stretch the margin keeps after the glue froze it (1: none; ``tau``: the sheet's,
        i.e. unglued latex).  The SI's "stretch factor near 2" is the sheet released
        *after* the margin was frozen, so it does not apply to the margin.
    clearance : bool
        The printed bumpers are ``UnitCell.clearance`` (0.05 mm) short at every tip
        (``scad/bumper.scad``; the reference's printing gap), so a cell closes that much
        further than the target: each bracket spring's contact length is its target
        length minus ``clearance / |n_xy|`` for each of its two bumpers (``n_xy`` = the
        in-plane part of the bumper's end-plane normal, as in
        :func:`pysolver.design.layout.footprint_rectangles` with ``printed=True``).
    membrane_temperature : bool
        Rubber elasticity is entropic: at a fixed stretch the latex's stress is
        proportional to the absolute temperature.  In the water the membrane modulus is
        ``mu * (water_temp_c + 273.15) / (lab_temp_c + 273.15)`` (x 1.115 for 56 and 22
        deg C); the dry rest is back at ``lab_temp_c``.
    water_temp_c : float, deg C
        Water temperature (SI Note 5 step 8: 56 deg C).
    lab_temp_c : float, deg C
        Room temperature at which the membrane's modulus and relaxation were measured and
        the shell was fabricated and scanned (assumed 22 deg C; 20-25 changes the factor by
        +-0.9 %).
    contact : bool
        Barrier contact between bases that are not neighbours (IPC Toolkit, ``ipctk``):
        every base a closed prism; no two non-neighbouring prisms pass through each other.
    contact_dhat_mm : float, mm
        Distance below which the barrier acts (below the 0.6 mm that bumpers keep between
        neighbours).
    contact_stiffness : float, N/mm
        Barrier stiffness kappa (energy ``kappa * -(d - dhat)^2 ln(d / dhat)``; 10 N/mm gives
        ~1 N at a tenth of dhat, the scale of the membrane's pull on a cell).
    contact_sides : int
        Sides of the prism that stands for a base disc.
    bracket_bending : bool
        Out-of-plane bending of the brackets (the 1 mm x h section): a rotational spring on
        the relative tilt of the two bases of every cell, its stiffness estimated from the
        brackets' current in-plane stiffness (``sim.model.physics.bending_stiffness``).
    """

    relaxation: bool = False
    stretch_to_glue_min: float = 10.0
    glue_to_water_min: float = 10.0
    gravity: bool = False
    dry_rest: bool = False
    drying_min: float = 15.0
    print_density: float = 1.18
    water_density: float = 0.985
    latex_density: float = 0.93
    gravity_mm_s2: float = 9810.0
    face_down: str = "bottom"
    ground_stiffness: float = 1e3
    ground_points: int = 8
    rim: bool = False
    rim_margin_mm: float = 1.0
    rim_stretch: float = 1.0
    contact: bool = False
    contact_dhat_mm: float = 0.1
    contact_stiffness: float = 10.0
    contact_sides: int = 8
    bracket_bending: bool = False
    clearance: bool = False
    membrane_temperature: bool = False
    water_temp_c: float = 56.0
    lab_temp_c: float = 22.0

    SWITCHES = ("clearance", "relaxation", "membrane_temperature", "gravity", "dry_rest", "rim",
                "contact", "bracket_bending")
    RANGES = {"stretch_to_glue_min": (0.0, 1e5), "glue_to_water_min": (0.0, 1e5),
              "drying_min": (0.0, 1e5), "rim_stretch": (1.0, 10.0),
              "ground_points": (3, 64), "contact_sides": (3, 64),
              "water_temp_c": (0.0, 100.0), "lab_temp_c": (0.0, 100.0)}
    """Accepted ranges (inclusive) of the options that are not simply positive; the
    barrier distance ``contact_dhat_mm`` must also stay below the gap that the bumpers keep
    between neighbouring bases, ``2 UnitCell.min_bumper`` (0.6 mm)."""

    @property
    def any(self) -> bool:
        """Any effect switched on."""
        return any(getattr(self, k) for k in self.SWITCHES)

    def switched_on(self) -> list:
        return [k for k in self.SWITCHES if getattr(self, k)]

    def to_dict(self) -> dict:
        return asdict(self)

    def temperature_factor(self, wet: bool = True) -> float:
        """Factor on the membrane modulus: ``T_water / T_lab`` (absolute temperatures) in
        the water with ``membrane_temperature`` on, else 1."""
        if not (self.membrane_temperature and wet):
            return 1.0
        return (self.water_temp_c + 273.15) / (self.lab_temp_c + 273.15)


RELAXATION_PRONY = (
    (1.0e1, 3.16227766e1, 1.0e2, 3.16227766e2, 1.0e3, 3.16227766e3, 1.0e4, 3.16227766e4, 1.0e5),
    (0.80176665, 0.02033809, 0.00262854, 0.02778007, 0.02581137, 0.05390961, 0.02105795, 0.0,
     0.01616499, 0.03054273),
)
"""Membrane stress relaxation at stretch 3 (SI Fig. 10,
``data/material-measurements/rubber_stress_relaxation.csv``), normalised Prony series
``g(t) = g_inf + sum_i g_i exp(-t / tau_i)``, ``g(0) = 1``: ``(tau_i (s), (g_inf, g_i...))``.
Fitted by :func:`pysolver.material.relaxation.fit_relaxation` (NNLS, relaxation times fixed at
half decades, samples weighted by ``1/sqrt(t)``); a test refits it from the CSV."""


UNIT_CELL = UnitCell()
MODEL_LIMITS = ModelLimits()
SUPPORT_FRAME = SupportFrame()
SIM = SimConstants()
PHYSICS_OFF = PhysicsOptions()
"""Every effect off: the reference simulator's model (``--physics none``)."""
PHYSICS_DEFAULT = PhysicsOptions(clearance=True)
"""The simulator's default physics (``--physics default``), chosen on the printed spiral's
scan (issue #32): the effects that bring the simulation closer to the scan with measured or
fabrication-given parameters.  The table of every option and the reasons are in
``docs/physics.md``."""
tol = Tolerances()
MODEL_FILES = ModelFileRules()
UNCERTAINTY = Uncertainty()
TOLERANCE_RUN = ToleranceRun()

LAYERS = ("top", "bottom")
"""Layer names.  ``top`` = +z in the flat print frame = +face-normal side of the
target (the reference's ``o``); ``bottom`` = -z = -normal side (``u``)."""


def layer_sign(layer) -> int:
    """+1 for the top layer (index 0 / ``"top"``), -1 for the bottom layer (1 / ``"bottom"``)."""
    if layer in (0, "top"):
        return 1
    if layer in (1, "bottom"):
        return -1
    raise ValueError(f"layer must be 0/'top' or 1/'bottom', got {layer!r}")


PAPER_BRACKET_HEIGHT_MM = 1.0
"""Bracket height of the paper's specimens: the material models fitted before the model file
recorded its bracket geometry were fitted on these brackets."""

DATA_DIR = Path(__file__).resolve().parent / "data"
"""The committed model files (``bracket_model.json``, ``membrane_model.json``)."""
MEMBRANE_MODEL_FILE = DATA_DIR / "membrane_model.json"
"""The committed membrane model (``make membrane-model`` re-fits it)."""


def check_unit_cell(params: UnitCell) -> None:
    """Check the user-variable tolerances of a unit cell against :class:`~pysolver.params.Limits`.

    Raises
    ------
    InputError
        Naming the option, its value, the allowed range and a fix.
    """
    for opt, v, (lo, hi), why in (
            ("--min-bumper", params.min_bumper, LIMITS.min_bumper_mm,
             "the paper uses 0.3 mm, most reference examples 0.1 mm"),
            ("--min-gap", params.min_gap, LIMITS.min_gap_mm,
             "the paper and the reference examples use 0.1 mm")):
        if not (math.isfinite(v) and lo <= v <= hi):
            raise InputError(f"{opt} {v!r} mm is outside {lo:g}-{hi:g} mm",
                             fix=f"give a length in that range ({why})")
    lo, hi = params.shortest_cell(), LIMITS.max_cell_length_mm
    v = params.max_cell_length
    if not (math.isfinite(v) and lo < v <= hi):
        raise InputError(
            f"--max-cell-length {v!r} mm is outside {lo:g}-{hi:g} mm: no cell is shorter than "
            f"2 (base radius + min bumper) + min gap = {lo:g} mm, and the bracket model is "
            f"measured up to {LIMITS.model_max_central_length_mm:g} mm (used up to {hi:g} mm)",
            fix=f"give a length above {lo:g} and up to {hi:g} mm (default "
                f"{UNIT_CELL.max_cell_length:g} mm)")


__all__ = ["check_unit_cell", "PAPER_BRACKET_HEIGHT_MM", "DATA_DIR", "MEMBRANE_MODEL_FILE",
           "DEFAULT_REFINE", "LIMITS", "MODEL_LIMITS", "ModelLimits", "REPORT",
           "ReportThresholds", "Limits", "UnitCell", "SimConstants",
           "Tolerances",
           "SupportFrame", "SUPPORT_FRAME",
           "PhysicsOptions", "PHYSICS_OFF", "PHYSICS_DEFAULT", "RELAXATION_PRONY",
           "ModelFileRules", "UNIT_CELL", "SIM", "tol", "MODEL_FILES", "LAYERS", "layer_sign",
           "Uncertainty", "ToleranceRun", "UNCERTAINTY", "TOLERANCE_RUN"]


@dataclass(frozen=True)
class Fabrication:
    """Numbers of the fabrication procedure (SI Note 5) used by the report's fabrication
    sheet and the membrane stretch template (``sim/fabrication.py``).

    Attributes
    ----------
    star_diameters_mm : tuple of float, mm
        Tip-circle diameters D of the star-shaped stretching devices the template can be
        drawn for (the reference's marker script: 200, 400, 500 mm).
    star_teeth : int
        Teeth of the device = markers on the sheet (16-point star).
    release_stretch : float
        Stretch factor the sheet is released to before cutting ("near 2").
    cut_margin_mm : float, mm
        Latex left around the shell when cutting (in the glued, stretched state).
    sheet_wrap_mm : float, mm
        Sheet beyond the marker circle, to wrap around the teeth (unstretched).
    pin_diameter_mm : float, mm
        Push-pin shaft through the alignment holes (reference push_pin.scad: r 0.4).
    water_c : float, degC
        Water temperature of the morphing bath.
    glue_wait_min, dry_min : float, min
        Wait after gluing before releasing the sheet; drying after the bath.
    marker_r_mm : float, mm
        Radius of a marker dot drawn on the template.
    """

    star_diameters_mm: tuple = (200.0, 400.0, 500.0)
    star_teeth: int = 16
    release_stretch: float = 2.0
    cut_margin_mm: float = 3.0
    sheet_wrap_mm: float = 15.0
    pin_diameter_mm: float = 0.8
    water_c: float = 56.0
    glue_wait_min: float = 5.0
    dry_min: float = 15.0
    marker_r_mm: float = 1.5


FABRICATION = Fabrication()
__all__ += ["Fabrication", "FABRICATION"]


@dataclass(frozen=True)
class Sequencing:
    """Settings of the automatic sequencing landscape (:mod:`pysolver.design.sequencing`):
    where parts of the target lie over other parts (the petals of a closed bud), the part
    underneath must be in place before the one on top arrives, else they jam halfway.

    Attributes
    ----------
    reach_mm : float, mm
        Two points of the target closer than this, in space, face each other ...
    detour : float
        ... when the path between them on the surface is over ``detour`` times longer.
    min_pairs : int
        Fewest facing vertex pairs that make an overlap (fewer are ignored as noise).
    saddle_ratio : float
        Two lobes of the surface (watershed basins of the distance to the rim) stay apart when
        the neck between them is under ``saddle_ratio`` of the smaller lobe's half-width;
        wider necks merge them into one part.
    times_s : (2,) float, s
        Completion times of the first and of the last part (the paper's cover: 30-80 s).
    min_separation_s : float, s
        When the build maps a sequenced landscape onto the times the cells can reach
        (``program_design(fit_landscape=True)``), successive parts stay at least this far
        apart.  The map that clamps fewest cells alone squeezed the cover's 30-80 s into
        58-59 s; the simulated completion times scatter by an RMS 9-11 s around ``t*``
        (:mod:`pysolver.temporal.program`), so parts closer than that may close together.
    """

    reach_mm: float = 12.0
    detour: float = 3.0
    min_pairs: int = 20
    saddle_ratio: float = 0.75
    times_s: tuple = (30.0, 80.0)
    min_separation_s: float = 10.0


SEQUENCING = Sequencing()
__all__ += ["Sequencing", "SEQUENCING"]
