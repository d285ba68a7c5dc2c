"""Temporal programming and its refinement from the simulation (SI Note 4; beyond the paper).

Source: morphshell's choices (the reference programs thicknesses by hand-tuned rules,
``simulator.md`` §10); the measurements behind a value are given with it.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import InputError


@dataclass(frozen=True)
class Programming:
    """Settings of the thickness solve (:mod:`pysolver.temporal.program`) and of the timing
    refinement from the simulation (``--refine``).

    Source: morphshell's (module docstring); the paper programs each cell once, without a
    refinement.

    Attributes
    ----------
    max_clamped_fraction : float
        Largest fraction of cells whose thickness is clamped to the printable range for a
        temporal program to be feasible; above it the landscape is refused, naming the
        achievable range.
    fit_clamped_fraction, fit_width_fraction : float
        A shape's own landscape that clamps at most ``fit_clamped_fraction`` of the cells is
        kept as given (a map would trade its times for a few cells: dome's 43-68 s, 7.1 %
        clamped, went onto 1-92 s, 5.2 %, and its timing RMS from 8 to 12 s); one that
        clamps more is mapped onto the achievable times (the program stage's fit) by the
        widest order-keeping map that clamps at most ``fit_clamped_fraction`` of the cells,
        then, among the maps at least ``fit_width_fraction`` as wide, by the one clamping
        fewest; when every map clamps more, by the one clamping fewest.  The
        fewest-clamping map alone could squash a landscape to a near-constant: petal's
        35-75 s onto 56-62 s (6.9 % clamped; completion order against t*: Spearman 0.55;
        with these rules, at 6ab95a1, 31-65 s, 9.2 %, Spearman 0.925) and the spiral's onto
        a constant; it kept the cells' count, not the order the landscape asks for.  The
        width fraction keeps the allowance from buying a few seconds of width with cells.
        That map is now the refusal's suggestion (and the fit's when every map clamps more
        than ``fit_clamped_fraction``): once a cell
        is timed by its slower layer, the late end of the achievable times opened and the
        widest map stretched weave's 30-85 s onto 40-119 s (timing RMS 1.1 -> 3.3 s); the fit
        takes the map that moves the cells' times least among those that clamp at most
        ``fit_clamped_fraction`` and keep the order visible (``fit_order_spearman``;
        :func:`pysolver.temporal.program._nearest_map`): weave 39-83 s.
        0.10 is the project's timing bar for a programmed shell (at most 10 % clamped; the
        reference's cover with its own landscape: 9.5 %).
    fit_order_spearman : float
        A shape's own landscape that clamps at most ``fit_clamped_fraction`` is still
        stretched (order kept, about the middle of its cells' times) when its order would
        not survive a print's own timing scatter: when its cells' times spread (sd over
        cells) less than ``k`` times the RMS over cells of the completion-time sd that the
        per-bracket thickness scatter gives them (:func:`pysolver.temporal.cell_time.timing_sd`).
        ``k`` is the spread over noise at which two jointly normal variables have the rank
        correlation ``fit_order_spearman``: ``r = 2 sin(pi rho_s / 6)``,
        ``k = r / sqrt(1 - r^2)`` (2.17 for 0.9).  The stretch is the narrowest that reaches
        ``k`` (:func:`pysolver.temporal.program._spreading_map`).  0.9 is the project's
        timing-order bar (issue #42: Spearman >= 0.9).  On dome, whose 44-68 s landscape
        every cell reaches once a cell is timed by its slower layer, the cells' times spread
        5.8 s against 6.3 s of print scatter (Spearman 0.61 simulated as given): its
        landscape stretched from 44-68 s onto 27-87 s; spiral (12.4 s against 6.1 s) from
        35-80 s onto 34-81 s; petal (15.6 s against 5.2 s) kept.  Strictly between 0 and 1.
    fit_order_rounds : int
        Times the stretch of ``fit_order_spearman`` is re-estimated on the stretched
        programme (the predicted sd moves with the times): on dome the stretch went 2.333,
        2.480, 2.488, 2.4884 and its order test 0.941, 0.997, 1.000 of the target; spiral's
        1.068, 1.065, 1.065.  At least 1.
    bisection_steps : int
        Bisection steps of the thickness and completion-time solves (50 halvings of the
        0.30-0.65 mm range or the model's 120 s: 3e-16 mm and 1e-13 s, the
        round-off of the values).
    refine_damping : float
        Fraction of the timing error (``t* - t_sim``) corrected per refinement round.
    refine_open_layer_mm : float, mm
        A layer still open at the end of a simulation, in a cell that never completes,
        is made this much thinner by the next refinement round.
    refine_extra_rounds : int
        Rounds the refinement adds after the ones asked for while its best round still
        has cells that never complete (each one more simulation).
    membrane_factor_max_area : float, mm^2
        Largest flat triangle of the membrane mesh of a design's own stencil (per-cell
        membrane factors, :func:`pysolver.temporal.membrane_model.cell_membrane_factors`).
    membrane_contraction_min : float
        Smallest uniform contraction (current / flat size) of the stencil estimated from the
        cells' closing distances for the per-cell membrane factors.
    robust : bool
        Programme each cell's layers against the per-bracket thickness scatter
        (:func:`pysolver.temporal.program.robust_layers`: the layer whose time is less
        sensitive to its thickness times the cell, the other closes a little earlier).
        Measured in ``docs/results.md`` (issue #45); off by default.
    robust_max_lead_s : float, s
        Most that :func:`pysolver.temporal.program.robust_layers` moves a cell's other layer
        earlier.  The time model treats the two layers as independent; in the simulator a
        layer closed long before the other changes when the other closes: on petal (one
        refinement round) cells whose other layer led by more than 10 s missed their time by
        13.2 s RMS (4.1-5.8 s as programmed by default), those led by 5-10 s by 3.0 s
        (2.5 s), those by under 5 s by 4.4 s (4.2 s).
    robust_grid : int
        Steps of the grid on which :func:`pysolver.temporal.program.robust_layers` chooses
        how much earlier the other layer closes (the expected error is smooth in it: 40 steps
        of at most 4 sd).
    """

    max_clamped_fraction: float = 0.5
    fit_clamped_fraction: float = 0.10
    fit_width_fraction: float = 0.9
    fit_order_spearman: float = 0.9
    fit_order_rounds: int = 3
    bisection_steps: int = 50
    refine_damping: float = 0.8
    refine_open_layer_mm: float = 0.1
    refine_extra_rounds: int = 2
    membrane_factor_max_area: float = 1.0
    membrane_contraction_min: float = 0.5
    robust: bool = False
    robust_max_lead_s: float = 5.0
    robust_grid: int = 40

    def __post_init__(self):
        if not 0.0 < self.fit_order_spearman < 1.0:
            raise InputError(f"Programming.fit_order_spearman = {self.fit_order_spearman!r}: "
                             "a rank correlation strictly between 0 and 1",
                             fix="give a value in (0, 1), e.g. the project's 0.9")
        if int(self.fit_order_rounds) < 1:
            raise InputError(f"Programming.fit_order_rounds = {self.fit_order_rounds!r}: at "
                             "least one round", fix="give an integer >= 1, e.g. 3")


PROGRAMMING = Programming()

DEFAULT_REFINE = 1
"""Rounds of timing refinement from the simulation, the one default of ``morphshell build``,
``make`` and :func:`pysolver.build.build`."""



@dataclass(frozen=True)
class Coupon:
    """The timing coupon (``morphshell coupon``) and its fit (``morphshell calibrate-time``).

    Source: morphshell's (issue #45).  The coupon is the paper's flat test patch
    (:func:`pysolver.design.surfaces.regular`) cut to a strip: its cells are timed in the
    bath and fitted with the programming's own bracket/membrane time model
    (:mod:`pysolver.temporal.coupon`).

    Attributes
    ----------
    rows, cols : int
        Triangle rows and columns of the strip (``regular:rows=..,cols=..``): 2 x 6 gives
        4 interior cells (both ends of their stencil edge inside) and 24 boundary cells.
    central_length_mm : float, mm
        Flat central length of every cell.  9 mm is the longest flat cell of the built-in
        shapes (petal: 8.9-9.3 mm); at this length an interior cell closes within the
        material model's 120 s for every printable thickness (0.30-0.65 mm), so its
        brackets span the programmable range.
    time_margin_s : float, s
        A cell is timed when the shipped model closes it at least this long before the end
        of the model's time range (a later cell could be censored in the bath).
    reading_sd_s : float, s
        Reading error of one closing time from a phone video (a frame is 1/30 s; the moment
        the bumpers touch is judged within about a second).  Floor of the fit's residual sd.
    min_cells : int
        Fewest timed cells a fit accepts (two parameters need redundancy to give a
        confidence interval).
    min_thickness_spread_mm : float, mm
        Smallest range of bracket thickness among the timed cells a fit accepts.
    compliance_bounds : (float, float)
        Range of the fitted bracket compliance factor ``s`` (a print 5x stiffer or softer
        than the model is a mistake, not a calibration).
    modulus_bounds : (float, float)
        Range of the fitted membrane modulus factor.
    max_correlation : float
        The membrane modulus is fitted with the compliance only when the data separate them:
        the estimates' correlation is at most this and the modulus interval is finite;
        otherwise the modulus is kept at 1 (the compliance then carries both).
    confidence : float
        Level of the printed confidence intervals.
    later_layer : bool
        The fit models each coupon cell's closing time as the *expected* time of the later of
        its two layers under the per-bracket thickness scatter
        (``thickness_sd`` of :func:`pysolver.temporal.coupon.fit_coupon`, by default
        :data:`pysolver.params.UNCERTAINTY`'s; :func:`pysolver.temporal.coupon.
        expected_closing_times`, the later layer by Clark's moments,
        :func:`pysolver.temporal.cell_time.later_layer_moments`), not as the later nominal layer: a
        printed cell closes late on average, and a fit that ignores it reads the lateness as
        a stiffer bracket (measured: ``bench/bench_coupon_bias.py``, docs/results.md, issue
        #45).  False: the nominal time (the fit before this option).
    later_layer_rounds : int
        Times the lateness is evaluated at the current fit and the compliance fitted again
        (it depends on the print's factors only through each bracket's sensitivity; measured
        on 12 synthetic coupons, compliance 0.6-1.8: 2 rounds give the compliance of a fit
        that evaluates the lateness at every step within 1.8 %, with fewer model evaluations).
    """

    rows: int = 2
    cols: int = 6
    central_length_mm: float = 9.0
    time_margin_s: float = 10.0
    reading_sd_s: float = 1.0
    min_cells: int = 4
    min_thickness_spread_mm: float = 0.1
    compliance_bounds: tuple = (0.2, 5.0)
    modulus_bounds: tuple = (0.3, 3.0)
    max_correlation: float = 0.95
    confidence: float = 0.95
    later_layer: bool = True
    later_layer_rounds: int = 2


COUPON = Coupon()

__all__ = ["Programming", "PROGRAMMING", "DEFAULT_REFINE", "Coupon", "COUPON"]
