"""The stencil: its search (vertex count, seeds, rim inset), its optimisation, and the
layout checks.

Source: morphshell's; each value says what it was measured on.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class StencilSearch:
    """Settings of the stencil generation (:mod:`pysolver.design.remesh`,
    :mod:`pysolver.design.stencil_opt`, :mod:`pysolver.design.count_search`) and of the
    layout checks (:mod:`pysolver.design.checks`).

    Source: morphshell's (the reference remeshes by hand in its GUI, ``pipeline.md`` §2.2);
    the measurements behind a value are given with it.

    Attributes
    ----------
    dense_faces : int
        User meshes are resampled to about this many well-shaped faces before flattening.
    min_boundary_points : int
        Fewest points on the stencil's rim.
    lloyd_iterations : int
        Weighted Lloyd iterations of the CVT in the conformal plane.
    lloyd_softness : float
        Softness of the Lloyd iterations' Voronoi owners (:func:`pysolver.design.remesh.
        _soft_owners`): each quadrature point is shared among its four nearest generators
        with weights ``exp(-(d^2 - d_1^2) / (softness d_4^2))``.  Hard owners made each
        step jump with the last bits of the input (the petal's N=117 stencil moved 0.43 mm
        under a 1e-7 jitter); soft ones keep the step continuous.  0.05 keeps a share
        under exp(-20 (1 - d_1^2 / d_4^2)) for all but the nearest few.
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
        Weight of the squared log shortfall of a base centre's clearance; the hard limit is
        :func:`~pysolver.design.stencil_opt.accept_step`'s.  200: with a landscape, 1000
        made the timing rounds' objective stiff, twice the L-BFGS iterations (petal's
        143-vertex candidate: 637 + 908, objective 16.198; with 200, 289 + 373 and 16.167;
        cover's 380-vertex one 1034 + 1605 and 519 + 654).  100 halved them again, but the
        count search then took petal to 135 vertices, a design with one rim cell left open
        in simulation (WARN).  Without a landscape they agree (the stand's 283-vertex
        candidate: 1.01370 and 1.01375).
    opt_clearance_slack : float
        Log shortfall of the clearance (2 %) a round may leave and still be kept (a hard
        limit of :func:`pysolver.design.stencil_opt.accept_step`).
    opt_backtracks : int
        Halvings of a round's step back toward its start tried when the L-BFGS point breaks
        a hard limit or does not improve the exact objective: a soft penalty's overshoot
        never costs the whole round.
    opt_stiffen : float
        When no point of the step is kept, the round is solved once more with the clearance
        penalty this many times stiffer.
    opt_slide_rim : bool
        The rim vertices slide along the curve the CVT put them on
        (:class:`pysolver.design.stencil_opt.RimCurve`) in each candidate's optimisation.
        Held, the longest flat cell was a rim cell at every count of the stand's search and
        moved by up to 1.7 mm between neighbouring counts (``bench/scan_counts.py``; figures
        in ``docs/results.md``, "The rim slides").
    opt_trust : float
        Trust radius of each outer round, as a fraction of the stencil's median flat edge:
        no free vertex coordinate moves further in one round, nor a rim vertex further along
        the rim (box bounds of L-BFGS-B).  The round's lift is linearised at its start, so a
        round left free ran L-BFGS far past where the linearisation holds; the exact check
        then kept an eighth of the step, or a half, and which of the two moved with the last
        bits (petal, 131 vertices: scale3d 0.96 or 1.06 after two rounds, as installed or
        under ``OPENBLAS_CORETYPE=Sandybridge``).  Bounded, every round of petal's first
        candidate is kept whole, the objective after 8 rounds is 10.5 (16.0 free), and the
        two conditions agree to 0.1 % in scaling and 0.03 mm in the longest cell.  (0.2:
        a half step again in the first round; 0.05: 12.0 after 8 rounds.)
    opt_prox, opt_gtol, opt_memory, opt_prox_iterations : float, float, int, int
        Each unpinned round minimises its linearised objective plus
        the proximal term ``opt_prox / e^2 ||x - x0||^2 / 2`` (``e`` the median flat edge,
        mm; ``x0`` the round's start) until the projected gradient is under ``opt_gtol``
        (1/mm), with ``opt_memory`` L-BFGS corrections and at most ``opt_prox_iterations``
        iterations (a guard: the rounds measured took 80-1300).  A round then ends at a
        minimum, not where an iteration budget stops L-BFGS's path, which 1e-9 of the input
        or another code path moved: the stand's 283-vertex candidate after two rounds had
        3D scaling 1.003 or 0.993 (jitter), and the count picked moved by a rung; with the
        proximal rounds, 1.01366 and 1.01370, and every case without a landscape in
        ``bench/bench_stability.py`` is stable but peer-hemisphere-0.1, whose 3D scaling
        the pinned polish sets (``docs/results.md``).  ``opt_prox`` 0.2
        agreed to 1e-5 but gained less per round; 0.02 took 2-4 times the iterations.  The
        term barely outweighs the objective's least curvature at the start (so the minimum
        is not unique in general), and the first round's step is still cut back by
        :func:`~pysolver.design.stencil_opt.accept_step` where it runs past the
        linearisation; both were the same under every perturbation measured.
        ``opt_memory`` 30: 0.8 s per candidate on the peer hemisphere at 176 vertices
        (1.7 s with scipy's 10).  With the timing term, inside the trust region
        (``opt_trust``; left free, petal's first round ran past its linearisation and kept
        1/16 of its step), to ``opt_timing_gtol`` with ``opt_timing_prox``.
    opt_timing_gtol, opt_timing_prox : float, float
        With the timing term, a proximal round runs until the projected gradient is under
        ``opt_timing_gtol`` (1/mm; its objective is stiffer than the longest cell's alone,
        and 1e-5 took 2-3 times the iterations; at 3e-4, after the timing estimates were
        refitted, saddle's 71-vertex candidate ended at 3D scaling 0.98011 as installed and
        0.9805 under Sandybridge, either side of the count search's tolerance, and the
        count moved by two rungs; at 1e-4, 0.98096 and 0.98090), with the proximal weight
        ``opt_timing_prox`` (over the median flat edge squared, as ``opt_prox``): the
        timing objective is less convex, and at 0.05 dome's 82-vertex candidate ended in
        one of two minima, 3D scaling 1.02092 as installed and 1.01712 jittered by 1e-9 (at
        0.2: 1.02100 and 1.02101; at 0.5: 1.02075 and 1.02074, and 1.02074-1.02075 with
        ``opt_timing_gtol`` 1e-3).  Petal's 143-vertex candidate: 0.99576 and 0.99578
        (1e-4: the same, in 490 iterations instead of 430; 0.05: 0.99571 in 660).  Budgeted
        rounds (100 iterations, before) gave dome 1.0185 and 1.0218 and moved dome and
        spiral by a rung under the perturbations of ``bench/bench_stability.py``.
    opt_fold_floor_deg : float, deg
        The half fold's tangent in the stencil objective is ``sqrt(tan^2 t + tan^2(f / 2))``
        with ``f`` this angle: smooth where a cell is flat, where the exact square root has
        a kink.  Its rounding noise there (a jump of 2e-7 in the objective over a step of
        1e-9 mm, petal) sent L-BFGS's path elsewhere with the last bits and stopped its line
        searches.  0.1 deg moves a flat cell's 3D rule by under 0.1 % and a folded one's
        (5 deg) by under 1e-5.
    timing_compression_floor : float, mm
        The timing estimates' compression ``x`` is floored smoothly, ``x_f log(1 +
        exp(x / x_f))`` (softplus): where a cell's bumpers nearly touch flat, ``log x``
        then has a slope of at most ``1 / x_f``; floored at 1e-30 it sent the timing rounds'
        line searches to a stop (petal).  The cells programmed compress by 0.6 mm or more
        (petal), where 0.1 mm moves ``log x`` by under 5e-4.
    opt_tiny : float
        Floor of the arguments of the barrier's and penalties' logarithms, and the guard
        added under the square root of the half fold's tangent in
        :func:`~pysolver.design.stencil_opt.layout_logs` (the optimiser's is
        ``opt_fold_floor_deg``).
    opt_rounds, opt_iterations : int
        Most outer rounds (re-lifting onto the target) per candidate of the count search,
        and L-BFGS iterations per round when rounds are budgeted (``opt_prox`` 0; proximal
        rounds run to ``opt_gtol`` or ``opt_timing_gtol``).
    opt_converge_rounds, opt_converge_iterations, opt_round_tol : int, int, float
        The stencil picked is optimised on, and held at scale 1, for up to
        ``opt_converge_rounds`` rounds of ``opt_converge_iterations`` L-BFGS iterations
        (proximal rounds: to ``opt_gtol``, or ``opt_timing_gtol`` with the timing term),
        until a round lowers the exact objective (log units) by less than ``opt_round_tol``
        (0.1 % of the longest cell).  Before each round had a trust region (``opt_trust``),
        the pick sat where L-BFGS's path happened to end unless it converged: jitters of
        1e-9 of the input moved the longest flat cell of ``dome:size=0.7`` over 8.34-8.52
        mm.  With the trust region six jitters give 7.453-7.464 mm; 4 rounds (8 gave
        petal the same stencil, 8.83 mm, in 5 s more).
    opt_barrier : float
        Weight of the log barrier that keeps flat triangles positively oriented.
    opt_timing_weight : float
        Weight of the timing misfit (:func:`pysolver.design.stencil_opt.timing_misfit`) in
        the stencil optimisation, when a time landscape is known (0 = off).
    timing_fastest, timing_slowest : tuple of float
        ``(c, a, e, k)`` of the estimates ``log t ~ c + a log b0 + e log x + k [boundary]``
        (t in s) of the fastest and slowest completion time a cell can reach (brackets of
        ``thickness_min`` and ``thickness_max``) from its bracket length b0 (mm),
        compression x (mm) and whether it lies on the rim.  Fitted by
        ``bench/fit_timing_estimate.py`` to the times temporal programming computed for the
        3273 cells of ten designs of the built-in shapes (code of ba73c6f): censored normal
        maximum likelihood, since programming's times end at the bracket model's 120 s;
        sigma 0.215 and 0.219 in log t.  Only the project's own shapes: the former
        coefficients were least squares on designs of ``../shared``'s cover and stand, test
        surfaces nothing may be tuned to (and programmed before the printed bumpers'
        clearance); on these designs they put the fastest 0.12 and the slowest 0.32 in log t
        too early on average (up to 0.27 and 0.50 per design).  The cover carrying the
        reference's landscape, held out, clamped 16.3 % of its cells with them, 8.7 % with
        these.  Fitting again on the designs these
        coefficients give does not settle: the cover then clamps 19.6 % and petal's timing
        warns (docs/results.md).  They only steer the stencil optimisation; temporal
        programming computes each cell's times from the material and membrane models.
    timing_margin : float
        The misfit narrows each cell's estimated range by this much (log time) at both ends:
        the estimates' own error is 0.22.
    opt_timing_iterations : int
        L-BFGS iterations per budgeted round (``opt_prox`` 0) when the timing term is on
        (it needs more than the longest cell alone).
    opt_cap_weight : float
        With the timing term, weight (per log^2) of the penalty that keeps the longest flat
        cell under ``max_cell_length - margin`` (exact at each round's start, smooth within
        it, so a soft cap: 0.07 mm over in ``tests/test_stencil.py``'s dome at 70 vertices;
        :meth:`~pysolver.design.stencil_opt.StencilObjective.timing`): without it the
        timing term can trade the count search's footing away (measured on cover: 3D
        scaling 0.82 at 418 bases).
    seeds : int
        CVT seeds tried at every vertex count the search visits, when none is given: the
        secant steers on their mean log 3D scaling and the pick takes the best of them
        (:mod:`pysolver.design.count_search`).  One seed's scaling scatters by a few per
        cent at a given count (petal: 0.97 to 1.11 at 120 vertices); with two, the petal,
        dome, saddle and spiral gave the same shell under relabelling, rigid motions and
        1e-7 jitters (``docs/results.md``), and a third changed none of them.
    count_start : float
        First vertex count of the search over the paper's estimate ``0.38 A / 7^2``
        (measured: the counts found are 1.4-1.7 x the estimate on cover, stand, petal,
        spiral).
    count_steps : int
        Secant steps of the vertex count toward a 3D scaling of 1.
    count_ladder : float
        Ratio of neighbouring vertex counts the search may try: every searched count is
        snapped to a rung ``round(count_ladder ** j)`` of one fixed geometric ladder.  A
        secant step to a continuous count, rounded to the next integer, moved with the last
        bits of the scaling it was computed from, and the search's path (and the count
        picked) with it: peer-saddle at 346 or 364 vertices under a 1e-9 jitter.  On the
        ladder a perturbation changes the count only when a step lands at the middle
        between two rungs, and then by one rung: 3 %, the bound issue #28 sets on the
        vertex count.
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
        Relative vertex counts tried around the secant result, each with every seed (none by
        default).
    margin : float, mm
        Preferred distance of the longest flat cell below the limit.
    opt_pin_weight : float
        Weight (per log^2) of the penalty that holds the exact 3D scaling at 1 when the chosen
        stencil is optimised once more for its longest flat cell per unit of scaling
        (:func:`pysolver.design.count_search.remesh_surface`; 0 = no second pass): the count
        search's scaling lands within a few per cent of 1 (its tolerance, and the seeds'
        noise), this pass brings it within 0.5 % (30 left 1-4 %).  It must outweigh the
        timing term (of order 10 on petal's landscape): at 100 petal's stencil stayed at
        0.970, at 1e4 it holds 0.995.  The scaling it holds is exact at each round's start
        and smooth within it: on the exact maximum's kinks the polish of the peer hemisphere
        (0.1 mm bumpers) ended at 1.012 as installed and 1.001 under Sandybridge; smooth,
        1.000 under every condition of ``bench/bench_stability.py``.
    hopeless_log_scale : float
        A candidate whose stencil, before optimisation, is off the size asked for by more than
        this (|log 3D scaling|, 42 %) is not optimised: the optimisation moves the scaling by
        up to 17 % (petal: 1.18 -> 0.99; the peer hemisphere and saddle 5-9 %), so it cannot
        become the pick; its figures still steer the secant steps.  Cuts the search's cost on
        targets whose first counts land far off.
    polish_tolerance : float
        The polish "held" the scaling at 1 when the stencil kept is within this (log) of it:
        the stencil is then at full size (:func:`pysolver.design.count_search.full_size`).
        A stencil that prints only further off is refused with a measured ``--size``: the
        shell is made smaller only when the user asks.  (Holding 0.969 when the stencil at
        1 left less than ``margin`` made the petal and the peer top print 3 % small.)
    refusal_size_factor : float
        A target none of whose stencils prints at any size is searched once more at this
        fraction of its size, so that its refusal names a measured smaller ``--size``.
    min_scale3d : float
        Smallest 3D scaling (the shell over the size asked for) a stencil may have, and
        ``1 / min_scale3d`` the largest: the count search picks among candidates within this
        band first, and the design stage refuses a stencil outside it, naming measured
        alternatives (a smaller ``--size`` that was tried, ``--min-bumper 0.1``), instead of
        printing a shell silently smaller or larger than asked.
    min_area_covered : float
        When the region inside the first rim inset covers less than this fraction of the
        target's 3D area (:meth:`pysolver.design.remesh.FlatDomain.region_covered`, a
        function of the target; it was the chosen stencil's own area, which put the petal at
        74.9 % or 75.1 % by where its rim points fell), the search also tries the
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
        the requested size); at least ``min_scale3d``.
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
    near_limit_fraction : float
        A cell whose flat central length is above this fraction of ``max_cell_length``
        (and not above it) is warned about as near the limit.
    rim_scale : {"auto", "kept", "free"}
        The conformal flattening's scale on the target's rim.  ``"kept"``: log-scale 0, rim
        lengths kept (the reference's layout).  ``"free"``: the boundary log-scale that
        lowers the measured bound (:func:`pysolver.design.feasibility.rim_log_scale`).
        ``"auto"``: kept; free when no stencil of the kept search prints at size, the count
        searched (not ``--vertices``), the CVT stencil (not pymeshlab's), and the bound with
        the rim free does not exclude the target (``remesh.rim_scale``).  Measured on the
        peer beetle (``--size 150 --min-bumper 0.1``): kept, the bound is 9.64 mm (over the
        9.5 mm limit) and the search's best is 9.72 mm; free, the bound is 8.94 mm (9.04 mm
        with the smoothed choice), and the polish at scale 1 reached 9.50-9.53 mm (0.969 of
        the size asked for gave 9.38 mm; the stencil is no longer made smaller unasked).
    rim_scale_sharpness : float, 1 / log
        Sharpness of the log-sum-exp that smooths the bound's two extremes when
        :func:`~pysolver.design.feasibility.rim_log_scale` chooses the rim's log-scale:
        smooth and strictly convex (with ``rim_scale_ridge``), so that its minimiser, unlike
        the linear programme's vertex, does not move with the last bits.  On the beetle,
        100 gives a bound of 9.04 mm against the linear programme's 8.94 mm (20: 9.27 mm,
        200: 8.99 mm).
    rim_scale_ridge : float
        Ridge (per squared log-scale of a boundary mode) of that choice: fixes the constant
        (which the bound does not see) and the modes the extremes do not reach.
    """

    dense_faces: int = 6000
    min_boundary_points: int = 6
    lloyd_iterations: int = 40
    lloyd_softness: float = 0.05
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
    opt_clearance_weight: float = 200.0
    opt_clearance_slack: float = 0.02
    opt_backtracks: int = 6
    opt_stiffen: float = 10.0
    opt_trust: float = 0.1
    opt_prox: float = 0.05
    opt_gtol: float = 1e-5
    opt_memory: int = 30
    opt_prox_iterations: int = 2000
    opt_tiny: float = 1e-30
    opt_fold_floor_deg: float = 0.1
    timing_compression_floor: float = 0.1
    opt_timing_gtol: float = 1e-4
    opt_timing_prox: float = 0.5
    opt_rounds: int = 2
    opt_converge_rounds: int = 4
    opt_converge_iterations: int = 100
    opt_round_tol: float = 1e-3
    opt_iterations: int = 50
    opt_barrier: float = 1e-3
    opt_timing_weight: float = 200.0
    timing_fastest: tuple = (6.47, -2.916, 0.767, 0.615)
    timing_slowest: tuple = (5.667, -0.816, 0.586, 0.309)
    timing_margin: float = 0.4
    opt_cap_weight: float = 1000.0
    opt_timing_iterations: int = 100
    seeds: int = 2
    count_start: float = 1.5
    count_steps: int = 4
    count_ladder: float = 1.03
    count_secant_min: float = 1e-9
    dense_min_angle_deg: float = 15.0
    dense_min_faces: int = 2000
    remesh_surface_dist: float = 0.05
    candidates: tuple = ()
    margin: float = 0.3
    opt_pin_weight: float = 10000.0
    opt_slide_rim: bool = True
    polish_tolerance: float = 0.02
    hopeless_log_scale: float = 0.35
    refusal_size_factor: float = 0.8
    min_scale3d: float = 0.95
    min_area_covered: float = 0.75
    remove_flaps: bool = True
    flap_min_angle_deg: float = 30.0
    trade_counts: tuple = (0.93, 0.86)
    trade_min_scale3d: float = 0.95
    trade_gain: float = 0.03
    timing_grading: float = 0.25
    near_limit_fraction: float = 0.95
    rim_scale: str = "auto"
    rim_scale_sharpness: float = 100.0
    rim_scale_ridge: float = 0.01


STENCIL = StencilSearch()

REFERENCE_MIN_BUMPER_MM = 0.1
"""The minimal bumper of most of the reference's examples (the paper says 0.3 mm), offered as
a measured alternative when a target cannot be printed."""

__all__ = ["StencilSearch", "STENCIL", "REFERENCE_MIN_BUMPER_MM"]
