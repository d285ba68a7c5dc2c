"""The stencil's settings, by topic: the candidate stencils (remeshing), the stencil
optimisation, the timing estimate, the vertex-count search, and the layout checks.

Each topic is a frozen dataclass whose fields carry their meaning, unit and source beside
their value; :class:`StencilSearch` is all of them at once, with the same flat field names
(``STENCIL.margin``, ``replace(STENCIL, grading=0.0)``: the names the code, the tests and
``docs/results.md`` use), so a topic can be read alone and the search is still given one
settings object.  A field whose type names no unit is dimensionless (a count, a ratio, a
weight of dimensionless log terms, or a sharpness on logs).

Source: morphshell's (the reference remeshes by hand in its GUI, ``pipeline.md`` §2.2),
measured on the shapes named with each value; the runs that chose the measured ones are in
``docs/results.md``, "How the stencil settings were chosen".
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class StencilRemesh:
    """Settings of the candidate stencils (:mod:`pysolver.design.stencil.remesh`): the dense
    resampling of the input, the CVT in the conformal plane and its relaxation, the rim
    (inset, flaps, the flattening's scale on it).

    Source: morphshell's, measured where a field says so (Runs: ``docs/results.md``, "How
    the stencil settings were chosen").
    """

    dense_faces: int = 6000
    """int: A user mesh that needs it (``dense_min_angle_deg``, ``dense_min_faces``) is
    subdivided at its edges' midpoints to about this many faces (log scale) before flattening."""
    dense_min_angle_deg: float = 15.0
    """float, deg: An input mesh whose smallest triangle angle is below this is resampled
    before flattening (its ears dropped, and subdivided when it has fewer faces than about
    ``dense_faces``: subdivision keeps its slivers' angles)."""
    dense_min_faces: int = 2000
    """int: An input mesh with fewer faces than this is resampled before flattening."""
    remesh_surface_dist: float = 0.05
    """float: Largest distance of the isotropic remeshing's surface from the input, relative to
    the target edge length."""
    min_boundary_points: int = 6
    """int: Fewest points on the stencil's rim."""
    lloyd_iterations: int = 40
    """int: Weighted Lloyd iterations of the CVT in the conformal plane."""
    lloyd_softness: float = 0.05
    """float: Softness of the Lloyd iterations' Voronoi owners
    (:func:`pysolver.design.stencil.remesh._soft_owners`): each quadrature point is shared among
    its four nearest generators with weights ``exp(-(d^2 - d_1^2) / (softness d_4^2))``. Runs:
    ``docs/results.md``, "How the stencil settings were chosen"."""
    relax_iterations: int = 100
    """int: Spring relaxation iterations (Persson and Strang's scheme) after the CVT."""
    relax_retriangulate: int = 5
    """int: Delaunay re-triangulation every this many relaxation iterations."""
    relax_fscale: float = 1.2
    """float: Rest length over mean length of the relaxation's repulsive springs (1.2, as in
    Persson and Strang)."""
    relax_step: float = 0.2
    """float: Explicit time step of the spring relaxation (Persson and Strang's ``deltat``, 0.2
    as theirs)."""
    grading: float = 0.5
    """float: Target spacing in 3D ``~ exp(u)^(-grading)`` (u = conformal log-scale): 0 =
    uniform in 3D (isotropic and uniform on the target), 1 = uniform in the plane. Runs:
    ``docs/results.md``, "How the stencil settings were chosen"."""
    timing_grading: float = 0.25
    """float: With a landscape the user gave, the stencil's 3D spacing follows ``(t /
    t_mean)^(-timing_grading)`` besides ``grading``
    (:func:`pysolver.design.stencil.remesh.time_spacing_log`): smaller, slower cells where the
    landscape asks for late times. Runs: ``docs/results.md``, "How the stencil settings were
    chosen"."""
    rim_insets: tuple = (0.5, 0.0)
    """tuple of float: Insets of the stencil boundary from the target's boundary, as fractions
    of the edge of the smallest regular cell the min-bumper rule allows (``sqrt(3) 2 (base_r +
    min_bumper)``, 7.3-8 mm), tried in order (0 = the stencil reaches the rim). Runs:
    ``docs/results.md``, "How the stencil settings were chosen"."""
    remove_flaps: bool = True
    """bool: Merge the two triangles of a rim vertex that has only two (a flap:
    :func:`pysolver.design.stencil.remesh.remove_flaps`). Runs: ``docs/results.md``, "How the
    stencil settings were chosen"."""
    flap_min_angle_deg: float = 30.0
    """float, deg: A flap is kept where the merged triangle would have a smaller angle (its
    inner vertex near the chord: a base would reach across the triangle's edge)."""
    rim_scale: str = "auto"
    """{"auto", "kept", "free"}: The conformal flattening's scale on the target's rim.
    ``"kept"``: log-scale 0, rim lengths kept (the reference's layout). Runs:
    ``docs/results.md``, "How the stencil settings were chosen"."""
    rim_scale_sharpness: float = 100.0
    """float, 1 / log: Sharpness of the log-sum-exp that smooths the bound's two extremes when
    :func:`~pysolver.design.stencil.feasibility.rim_log_scale` chooses the rim's log-scale:
    smooth and strictly convex (with ``rim_scale_ridge``), so that its minimiser, unlike the
    linear programme's vertex, does not move with the last bits. Runs: ``docs/results.md``, "How
    the stencil settings were chosen"."""
    rim_scale_ridge: float = 0.01
    """float: Ridge (per squared log-scale of a boundary mode) of that choice: fixes the
    constant (which the bound does not see) and the modes the extremes do not reach."""


@dataclass(frozen=True)
class StencilOptimiser:
    """Settings of the stencil optimisation (:mod:`pysolver.design.stencil.optimise`, its
    objective :mod:`pysolver.design.stencil.objective`): the objective's weights and
    penalties, the L-BFGS rounds, the polish's pin.

    Source: morphshell's, measured where a field says so (Runs: ``docs/results.md``, "How
    the stencil settings were chosen").
    """

    opt_sharpness: float = 60.0
    """float: Log-sum-exp sharpness of the smoothed maxima in the stencil optimisation."""
    opt_s3_weight: float = -0.7
    """float: Weight of log(3D scaling) beside log(longest flat cell) in the objective. Runs:
    ``docs/results.md``, "How the stencil settings were chosen"."""
    opt_min_angle_deg: float = 30.0
    """float, deg: Smallest flat corner angle left unpenalised: a base's disc (r 2 mm) must not
    reach across its triangle's edges."""
    opt_max_angle_deg: float = 90.0
    """float, deg: Largest flat corner angle left unpenalised (a 30-30-120 triangle puts its
    centroid 1.2 mm from its long edge per 12 mm)."""
    opt_centroid_edge_mm: float = 2.3
    """float, mm: Smallest distance from a base centre (flat centroid) to its triangle's edges
    in the scaled layout: a base's disc and bracket roots (r 2 mm) stay inside the membrane
    region the simulator's and the F_mem correction's meshes give each base (the reference's
    stencils keep >= 2.6 mm)."""
    opt_angle_weight: float = 100.0
    """float, per rad^2: Weight of the penalty on flat corner angles outside
    ``opt_min_angle_deg``-``opt_max_angle_deg``."""
    opt_clearance_weight: float = 200.0
    """float: Weight of the squared log shortfall of a base centre's clearance; the hard limit
    is :func:`~pysolver.design.stencil.optimise.accept_step`'s. Runs: ``docs/results.md``, "How
    the stencil settings were chosen"."""
    opt_clearance_slack: float = 0.02
    """float: Log shortfall of the clearance (2 %) a round may leave and still be kept (a hard
    limit of :func:`pysolver.design.stencil.optimise.accept_step`)."""
    opt_barrier: float = 1e-3
    """float: Weight of the log barrier that keeps flat triangles positively oriented."""
    opt_tiny: float = 1e-30
    """float: Floor of the arguments of the barrier's and penalties' logarithms, and the guard
    added under the square root of the half fold's tangent in
    :class:`~pysolver.design.stencil.objective.Scalings` (the optimiser's is
    ``opt_fold_floor_deg``)."""
    opt_fold_floor_deg: float = 0.1
    """float, deg: The half fold's tangent in the stencil objective is ``sqrt(tan^2 t + tan^2(f
    / 2))`` with ``f`` this angle: smooth where a cell is flat, where the exact square root has
    a kink. Runs: ``docs/results.md``, "How the stencil settings were chosen"."""
    opt_timing_weight: float = 200.0
    """float: Weight of the timing misfit (:func:`pysolver.design.stencil.objective.timing`) in
    the stencil optimisation, when a time landscape is known (0 = off)."""
    opt_cap_weight: float = 1000.0
    """float: With the timing term, weight (per log^2) of the penalty that keeps the longest
    flat cell under ``max_cell_length - margin`` (exact at each round's start, smooth within it,
    so a soft cap: Runs: ``docs/results.md``, "How the stencil settings were chosen"."""
    opt_pin_weight: float = 10000.0
    """float: Weight (per log^2) of the penalty that holds the exact 3D scaling at 1 when the
    chosen stencil is optimised once more for its longest flat cell per unit of scaling
    (:func:`pysolver.design.stencil.search.remesh_surface`; Runs: ``docs/results.md``, "How the
    stencil settings were chosen"."""
    opt_slide_rim: bool = True
    """bool: The rim vertices slide along the curve the CVT put them on
    (:class:`pysolver.design.stencil.optimise.RimCurve`) in each candidate's optimisation. Runs:
    ``docs/results.md``, "How the stencil settings were chosen"."""
    opt_rounds: int = 2
    """int: Most outer rounds (re-lifting onto the target) per candidate of the count search."""
    opt_iterations: int = 50
    """int: L-BFGS iterations per round when rounds are budgeted (``opt_prox`` 0; proximal
    rounds run to ``opt_gtol`` or ``opt_timing_gtol``)."""
    opt_timing_iterations: int = 100
    """int: L-BFGS iterations per budgeted round (``opt_prox`` 0) when the timing term is on (it
    needs more than the longest cell alone)."""
    opt_backtracks: int = 6
    """int: Halvings of a round's step back toward its start tried when the L-BFGS point breaks
    a hard limit or does not improve the exact objective: a soft penalty's overshoot never costs
    the whole round."""
    opt_stiffen: float = 10.0
    """float: When no point of the step is kept, the round is solved once more with the
    clearance penalty this many times stiffer."""
    opt_trust: float = 0.1
    """float: Trust radius of each outer round, as a fraction of the stencil's median flat edge:
    no free vertex coordinate moves further in one round, nor a rim vertex further along the rim
    (box bounds of L-BFGS-B). Runs: ``docs/results.md``, "How the stencil settings were
    chosen"."""
    opt_prox: float = 0.05
    """float: Weight of each unpinned round's proximal term ``opt_prox / e^2 ||x - x0||^2 / 2``
    (``e`` the median flat edge, mm), so that a round ends at a minimum, not where an iteration
    budget stops L-BFGS. Runs: ``docs/results.md``, "How the stencil settings were chosen"."""
    opt_gtol: float = 1e-5
    """float, 1/mm: A proximal round runs until its projected gradient is under this. Runs:
    ``docs/results.md``, "How the stencil settings were chosen"."""
    opt_memory: int = 30
    """int: L-BFGS corrections kept (30: 0.8 s per candidate on the peer hemisphere at 176
    vertices, 1.7 s with scipy's 10). Runs: ``docs/results.md``, "How the stencil settings were
    chosen"."""
    opt_prox_iterations: int = 2000
    """int: Most iterations of a proximal round: a guard (the rounds measured took 80-1300).
    Runs: ``docs/results.md``, "How the stencil settings were chosen"."""
    opt_timing_gtol: float = 1e-7
    """float, 1/mm: With the timing term, a proximal round runs until its projected gradient is
    under this (3e-4 let saddle's count move by two rungs between CPUs; at 1e-4 the rounds of one
    cover candidate ended 1e-4 apart between CPU code paths, the next round went to another
    minimum, and its 3D scaling differed by 3 %; at 1e-7 they agree to 1e-5 mm, for about twice
    the iterations). Runs: ``docs/results.md``, "How the stencil settings were chosen"."""
    opt_timing_prox: float = 0.5
    """float: The proximal weight with the timing term (over the median flat edge squared, as
    ``opt_prox``): the timing objective is less convex, and 0.05 let dome's 82-vertex candidate
    end in one of two minima. Runs: ``docs/results.md``, "How the stencil settings were
    chosen"."""
    opt_converge_rounds: int = 4
    """int: Most rounds the stencil picked is optimised on, held at scale 1 (4: 8 gave petal the
    same stencil in 5 s more). Runs: ``docs/results.md``, "How the stencil settings were
    chosen"."""
    opt_converge_iterations: int = 100
    """int: L-BFGS iterations per such round (budgeted rounds; proximal rounds run to
    ``opt_gtol``)."""
    opt_round_tol: float = 1e-3
    """float, log units: Those rounds stop when one lowers the exact objective by less than this
    (0.1 % of the longest cell)."""


@dataclass(frozen=True)
class TimingEstimate:
    """The closed-form estimate of the fastest and slowest time each cell can reach, from its
    bracket length and compression (:func:`pysolver.design.stencil.objective.log_time_range`):
    the optimiser's timing term and the count search's clamped fraction.

    Source: morphshell's, measured where a field says so (Runs: ``docs/results.md``, "How
    the stencil settings were chosen").
    """

    timing_fastest: tuple = (6.47, -2.916, 0.767, 0.615)
    """tuple of float: ``(c, a, e, k)`` of the estimate ``log t ~ c + a log b0 + e log x + k
    [boundary]`` (t in s, b0 and x in mm) of the fastest time a cell can reach (brackets of
    ``thickness_min``), fitted by ``bench/fit_timing_estimate.py`` on the built-in shapes. Runs:
    ``docs/results.md``, "How the stencil settings were chosen"."""
    timing_slowest: tuple = (5.667, -0.816, 0.586, 0.309)
    """tuple of float: The same for the slowest time a cell can reach (brackets of
    ``thickness_max``); sigma 0.219 in log t. Runs: ``docs/results.md``, "How the stencil
    settings were chosen"."""
    timing_margin: float = 0.4
    """float: The misfit narrows each cell's estimated range by this much (log time) at both
    ends: the estimates' own error is 0.22."""
    timing_compression_floor: float = 0.1
    """float, mm: The timing estimates' compression ``x`` is floored smoothly, ``x_f log(1 +
    exp(x / x_f))`` (softplus): where a cell's bumpers nearly touch flat, ``log x`` then has a
    slope of at most ``1 / x_f``; floored at 1e-30 it sent the timing rounds' line searches to a
    stop (petal). Runs: ``docs/results.md``, "How the stencil settings were chosen"."""


@dataclass(frozen=True)
class CountSearchSettings:
    """Settings of the vertex-count search (:mod:`pysolver.design.stencil.count_search`,
    :mod:`pysolver.design.stencil.candidates`): seeds and secant steps, the pick's size band
    and margin, the rim fallback, the polish, the trade for a landscape.

    Source: morphshell's, measured where a field says so (Runs: ``docs/results.md``, "How
    the stencil settings were chosen").
    """

    seeds: int = 2
    """int: CVT seeds tried at every vertex count the search visits, when none is given: the
    secant steers on their mean log 3D scaling and the pick takes the best of them
    (:mod:`pysolver.design.stencil.count_search`). Runs: ``docs/results.md``, "How the stencil
    settings were chosen"."""
    count_start: float = 1.5
    """float: First vertex count of the search over the paper's estimate ``0.38 A / 7^2``
    (measured: the counts found are 1.4-1.7 x the estimate on cover, stand, petal, spiral)."""
    count_steps: int = 4
    """int: Secant steps of the vertex count toward a 3D scaling of 1."""
    count_ladder: float = 1.03
    """float: Ratio of neighbouring vertex counts the search may try: every searched count is
    snapped to a rung ``round(count_ladder ** j)`` of one fixed geometric ladder. Runs:
    ``docs/results.md``, "How the stencil settings were chosen"."""
    count_secant_min: float = 1e-9
    """float: Smallest difference of log vertex counts of the last two trials over which the
    secant slope is taken (else the uniform-mesh slope 1/2)."""
    candidates: tuple = ()
    """tuple of float: Relative vertex counts tried around the secant result, each with every
    seed (none by default)."""
    margin: float = 0.3
    """float, mm: Preferred distance of the longest flat cell below the limit."""
    min_scale3d: float = 0.95
    """float: Smallest 3D scaling (the shell over the size asked for) a stencil may have, and
    ``1 / min_scale3d`` the largest: the count search picks among candidates within this band
    first, and the design stage refuses a stencil outside it, naming measured alternatives (a
    smaller ``--size`` that was tried, ``--min-bumper 0.1``), instead of printing a shell
    silently smaller or larger than asked."""
    polish_tolerance: float = 0.02
    """float: The polish "held" the scaling at 1 when the stencil kept is within this (log) of
    it: the stencil is then at full size (:func:`pysolver.design.stencil.candidates.full_size`).
    Runs: ``docs/results.md``, "How the stencil settings were chosen"."""
    polish_tries: int = 4
    """int: Most stencils polished at scale 1 before the count search gives up the size asked
    for (:meth:`pysolver.design.stencil.count_search.CountSearch.alternates`): the pick, the other
    starts of its count, then the starts of the next counts (nearest a mean scaling of 1 first)
    that keep the size and would print held at scale 1.  A polish that fails to hold is a
    threshold outcome of a long optimisation: refusing on one alone refused a shape or not with
    the last bits of its coordinates."""
    hopeless_log_scale: float = 0.35
    """float: A candidate whose stencil, before optimisation, is off the size asked for by more
    than this (|log 3D scaling|, 42 %) is not optimised: the optimisation moves the scaling by
    up to 17 % (petal: Runs: ``docs/results.md``, "How the stencil settings were chosen"."""
    min_area_covered: float = 0.75
    """float: When the region inside the first rim inset covers less than this fraction of the
    target's 3D area (``FlatDomain.region_covered``, a function of the target alone), the
    stencil without an inset is tried too and taken if it prints at least as well (narrow
    targets: the spiral's inset region covers 73 %). Runs: ``docs/results.md``, "How the stencil
    settings were chosen"."""
    refusal_size_factor: float = 0.8
    """float: A target none of whose stencils prints at any size is searched once more at this
    fraction of its size, so that its refusal names a measured smaller ``--size``."""
    trade_counts: tuple = (0.93, 0.86)
    """tuple of float: With a time landscape the user gave (``--time``, ``--time-file``),
    relative vertex counts below the chosen one also tried: larger cells are faster, and a
    landscape that asks for early times may clamp fewer cells on them
    (:func:`pysolver.design.stencil.optimise.estimated_clamping`). Runs: ``docs/results.md``,
    "How the stencil settings were chosen"."""
    trade_min_scale3d: float = 0.95
    """float: Smallest 3D scaling a traded stencil may have (the shell at least this fraction of
    the requested size); at least ``min_scale3d``."""
    trade_gain: float = 0.03
    """float: Smallest drop of the estimated clamped fraction that pays for the smaller
    shell."""


@dataclass(frozen=True)
class LayoutChecks:
    """Settings of the checks of the flat layout (:mod:`pysolver.design.checks`).

    Source: morphshell's, measured where a field says so (Runs: ``docs/results.md``, "How
    the stencil settings were chosen").
    """

    near_limit_fraction: float = 0.95
    """float: A cell whose flat central length is above this fraction of ``max_cell_length``
    (and not above it) is warned about as near the limit."""


@dataclass(frozen=True)
class StencilSearch(StencilRemesh, StencilOptimiser, TimingEstimate, CountSearchSettings,
                    LayoutChecks):
    """All the stencil's settings (:class:`StencilRemesh`, :class:`StencilOptimiser`,
    :class:`TimingEstimate`, :class:`CountSearchSettings`, :class:`LayoutChecks`) in one
    object with flat field names: what :func:`pysolver.design.stencil.remesh_surface` and
    :func:`pysolver.design.checks.check_layout` are given.

    Source: the topics' (each field beside its value in its topic's class).
    """


STENCIL = StencilSearch()

REFERENCE_MIN_BUMPER_MM = 0.1
"""The minimal bumper of most of the reference's examples (the paper says 0.3 mm), offered as
a measured alternative when a target cannot be printed."""

__all__ = ["StencilRemesh", "StencilOptimiser", "TimingEstimate", "CountSearchSettings",
           "LayoutChecks", "StencilSearch", "STENCIL", "REFERENCE_MIN_BUMPER_MM"]
