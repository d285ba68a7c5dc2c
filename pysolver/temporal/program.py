"""Temporal programming: bracket thicknesses from the time landscape (SI Note 4).

Every unit cell should finish morphing (its bumpers collide) at its programmed time
``t*`` = mean of the time landscape at the two ends of its stencil edge.  A cell
finishes when its brackets have softened enough that the membrane's pull can
compress them to the bumpers.  The thickness of each layer's brackets is chosen so
that this happens at ``t*`` (SI eq. 15)::

    F(b0, h_s, t*, x_s) = F_mem(b0, d1) / 4          for each layer s in (top, bottom)

* ``F(b, h, t, x)`` -- the bracket model (:mod:`pysolver.material`), force of **one
  single bracket** (N, compression positive) of flat length ``b`` and thickness ``h``
  after ``t`` s in hot water, compressed by ``x``.  Plasticity is ignored: on
  monotonic loading the simulator's plastic spring follows the same envelope.
* ``x_s = b0 - b1_s`` -- target compression of layer ``s``: ``b0`` =
  ``bracket_length_mm``, ``b1_s`` = ``collision_length_<layer>_mm`` (bumper contact).
* ``F_mem(b0, d1)`` -- the linearised membrane model
  (:mod:`pysolver.temporal.membrane_model`): the **whole cell's** membrane traction, carried by
  its **four** brackets (two per layer), evaluated at the actuated state
  ``d1 = b0 - (b1_top + b1_bottom) / 2`` (the membrane lies on the mid-plane).
  The per-bracket target is ``F_mem / 4`` for every bracket of the cell, so the layer
  that must compress more gets the thinner bracket (SI Fig. 8b).
* Per-cell correction ``k`` (``F_mem -> k F_mem``, :data:`CORRECTIONS`).  The paper
  multiplies boundary cells (an end of the shared edge on the stencil boundary) by 0.6
  (``correction="boundary"``).  The default ``"fem"`` meshes the design's own flat
  stencil, contracts it uniformly and reads each cell's FEM traction: interior cells get
  ``k`` = FEM / model (irregular stencils: 0.65-1.8, the stencil edge is longer or shorter
  than in the regular lattice the model was fitted on), boundary cells
  ``min(0.6, FEM / model)`` (cells whose edge has both ends on the boundary pull only
  ~0.1-0.2: with 0.6 they never close).  In simulations (tolerance 0.05 mm, achievable
  cells) this lowered the RMS timing error from 10.6 to 10.4 s (petal), 11.2 to 9.9 s
  (petal at size 0.7), 11.9 to 8.7 s (dome, landscape rescaled to 0-51 s) and 5.2 to
  2.0 s (regular), and raised the petal's rank correlation from 0.76 to 0.80.

Feasibility.  Thickness is printable in ``[0.30, 0.65]`` mm.  The thinnest bracket
gives the earliest completion time ``t_min`` of a layer, the thickest the latest
``t_max`` (found by bisection in time on the bracket model, within the model's time
range, 0-120 s).  A cell completes when its later layer closes, so its achievable range
runs from the later of its layers' earliest times to the later of their latest times
(:func:`~pysolver.temporal.cell_time.time_ranges`): a layer that cannot be as slow as
``t*`` gets its thickest bracket, closes early and waits at its bumpers while the other
layer times the cell.  (The paper's intersection of the two ranges clamped strongly folded
rim cells, whose little-compressed layer closes within 13-68 s even at 0.65 mm: 17 of the
petal's 21 clamped cells at a755258.)  A cell whose ``t*`` is outside is **clamped**: both layers
are programmed for the nearest achievable time, the cell is flagged in ``cells.csv``
(``clamped``) and listed in the summary.  If more than half of the cells are clamped the
landscape is refused with the achievable range in the message.

Completion.  A cell is complete when all 4 of its bracket springs are at their bumpers,
within ``UnitCell.clearance`` (0.05 mm, the size of the printing clearance, see
:func:`sim.model.collisions.completion_times`); the layers are programmed to close where the
simulator closes them, at the printed bumpers' contact (:func:`closing_lengths`).

Closing the loop (beyond the paper).  :func:`pysolver.refine.refine_design` compares simulated
completion times with ``t*`` and corrects the requested times of the thickness
solve, ``t_req <- clip(t_req + damping (t* - t_sim), t_min, t_max)``, re-solving and
re-simulating ``iterations`` times; the best iteration (lowest RMS timing error)
is kept.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import tables
from ..core.progress import say
from ..core.writes import atomic_write_text
from ..design.time_landscape import cell_target_times, write_landscape
from ..errors import InputError
from ..material.model import check_bracket_geometry
from ..mechanics import bumper_clearance
from ..params import PHYSICS_DEFAULT, PROGRAMMING, SEQUENCING, UNCERTAINTY, UNIT_CELL
from ..params import tol as TOL
from ..tables import PREDICTED_SD, read_stencil
from .cell_time import (
    bracket_target_force,
    completion_time,
    later_layer_moments,
    layer_sensitivity,
    load_material,
    robust_layers,
    solve_thickness,
    target_compressions,
    time_limit,
    time_ranges,
    timing_sd,
)
from .membrane_model import cell_membrane_factors, load_membrane_model
from .plots import plot_feasibility

PICTURE = "temporal_feasibility.png"
"""Time landscape picture with the clamped cells marked (in the design folder)."""
STAGE_FILE = "temporal.json"
"""Programming record (correction rule, per-cell membrane factors, summary), design folder."""
REFINE_LOG = "refine.json"
"""History of :func:`pysolver.refine.refine_design` (in ``<design>/sim/``)."""

CORRECTIONS = ("boundary", "fem")
"""How ``F_mem`` is adapted per cell.  ``"boundary"``: the paper's rule, x 0.6 on boundary
cells.  ``"fem"``: an FEM membrane on the design's own flat stencil
(:func:`pysolver.temporal.membrane_model.cell_membrane_factors`) gives every interior cell its
factor (irregular stencils: 0.65-1.8), and boundary cells get ``min(0.6, FEM factor)``
(cells whose edge has both ends on the boundary pull only ~0.1-0.2 and never close with
0.6)."""
DEFAULT_CORRECTION = "fem"


def _log(msg: str, progress: bool, stage: str = "program") -> None:
    say(stage, "", msg, progress)


# ----------------------------------------------------------------------------------------------
# programming
# ----------------------------------------------------------------------------------------------


def program_cells(b0, b1_top, b1_bottom, boundary, t_star, *, material, membrane,
                  t_request=None, boundary_factor=None, factor=None,
                  robust: bool | None = None) -> dict:
    """Thicknesses, achievable ranges and clamping for a set of cells (no file I/O).

    Parameters
    ----------
    b0, b1_top, b1_bottom : (n,) float, mm
        Flat bracket length and per-layer collision lengths.
    boundary : (n,) bool
    t_star : (n,) float, s
        Target completion times.
    material, membrane
        Bracket model object and :class:`~pysolver.temporal.membrane_model.MembraneModel`.
    t_request : (n,) float, s, optional
        Times to program instead of ``t_star`` (closing the loop); clamping is still
        judged on ``t_star``.
    boundary_factor : float, optional
        Weakening of boundary cells (default: the membrane model's, 0.6).
    factor : (n,) float, optional
        Per-cell factor on ``F_mem`` replacing the boundary rule (see
        :func:`membrane_factors`).
    robust : bool, optional
        Layers programmed against the thickness scatter (:func:`robust_layers`; default
        ``Programming.robust``).

    Returns
    -------
    dict of arrays: ``thickness`` (n, 2) mm (top, bottom), ``t_min``, ``t_max``,
    ``t_program`` (n,) s (the time the thicknesses are solved for), ``clamped`` (n,)
    bool, ``side`` (n,) int (-1 too early, +1 too late, 0 ok), ``x`` (n, 2) mm,
    ``d1`` (n,) mm, ``f_cell``, ``f_bracket`` (n,) N, ``t_sd_predicted`` (n,) s (the
    completion time's sd under the per-bracket thickness scatter, :func:`timing_sd`),
    ``lead`` (n,) s (how much earlier :func:`robust_layers` closes the other layer; 0).
    """
    t_star = np.asarray(t_star, float)
    if not np.all(np.isfinite(t_star)) or np.any(t_star < 0):
        bad = int(np.flatnonzero(~np.isfinite(t_star) | (t_star < 0))[0])
        raise InputError(f"cell {bad}: programmed time t* = {t_star[bad]} s is not a "
                         "non-negative number.", fix="give a time landscape of times >= 0 s.")
    x, d1 = target_compressions(b0, b1_top, b1_bottom)
    if np.any(x <= 0):
        bad = int(np.flatnonzero((x <= 0).any(axis=1))[0])
        raise InputError(f"cell {bad}: collision length >= bracket length "
                         f"(b0 = {np.asarray(b0)[bad]:.4g} mm, b1 = {np.round(b0[bad] - x[bad], 4)}"
                         " mm): the cell would not contract.",
                         fix="re-run the design stage (collision lengths must be shorter than "
                             "the flat bracket length).")
    f_cell, f_br = bracket_target_force(membrane, b0, d1, boundary, boundary_factor, factor)
    t_lo, t_hi, layer_min, _ = time_ranges(material, b0, x, f_br)
    want = t_star if t_request is None else np.asarray(t_request, float)
    lo_ok = np.where(np.isfinite(t_lo), t_lo, time_limit(material))
    t_prog = np.clip(want, lo_ok, np.maximum(lo_ok, t_hi))
    side = np.where(t_star < t_lo - TOL.time, -1, np.where(t_star > t_hi + TOL.time, 1, 0))
    side = np.where(np.isfinite(t_lo), side, 1)
    bb = np.repeat(np.asarray(b0, float)[:, None], 2, 1)
    h, _ = solve_thickness(material, bb, x, np.repeat(t_prog[:, None], 2, 1),
                           np.repeat(f_br[:, None], 2, 1))
    lead = np.zeros(len(t_prog))
    sd_h = UNCERTAINTY.thickness_sd
    if PROGRAMMING.robust if robust is None else robust:
        h, lead = robust_layers(material, h, b0, x, f_br, t_prog, layer_min, sd_h)
    return {"thickness": h, "t_min": t_lo, "t_max": t_hi, "t_program": t_prog,
            "clamped": side != 0, "side": side, "x": x, "d1": d1, "f_cell": f_cell,
            "f_bracket": f_br, "t_sd_predicted": timing_sd(material, h, b0, x, f_br, sd_h)[0],
            "lead": lead}


def _achievable_summary(t_star, t_lo, t_hi, t_limit, step: float = 1.0,
                        min_span: float = 0.0) -> dict:
    """Where the achievable times lie, and the order-preserving rescaling to suggest.

    Parameters
    ----------
    t_star, t_lo, t_hi : (n,) float, s
        Requested times and the achievable range of each cell.
    t_limit : float, s
        End of the material model's time range.
    step : float, s
        Grid of the candidate ends a, b.
    min_span : float, s
        Smallest width b - a of a suggested map (:func:`sequenced_span`); when no map of
        that width fits in [0, t_limit], any width is allowed.

    Returns
    -------
    dict
        ``common`` [a, b] s reachable by every cell (None if empty); ``earliest``,
        ``latest`` s; ``best_constant`` (time s, fraction of cells that can reach it);
        ``suggested_map`` {``t0``, ``t1``, ``a``, ``b``, ``fraction_clamped``,
        ``min_span_s``}: mapping the landscape's [t0, t1] linearly onto [a, b] s
        (a + min_span <= b, order kept) as :func:`_order_keeping_map` chooses it.
    """
    fin = np.isfinite(t_lo)
    out: dict = {"common": None, "earliest": None, "latest": None, "best_constant": None,
                 "suggested_map": None}
    if not fin.any():
        return out
    lo, hi = t_lo[fin], t_hi[fin]
    if lo.max() <= hi.min():
        out["common"] = [float(lo.max()), float(hi.min())]
    out["earliest"], out["latest"] = float(lo.min()), float(hi.max())
    grid = _end_grid(t_limit, step)
    lo_all = np.where(fin, t_lo, np.inf)
    cover = ((grid[:, None] >= lo_all - TOL.time) & (grid[:, None] <= t_hi + TOL.time))
    frac = cover.mean(axis=1)
    k = int(np.argmax(frac))
    out["best_constant"] = [float(grid[k]), float(frac[k])]
    t0, t1 = float(np.min(t_star)), float(np.max(t_star))
    span = float(min_span) if t1 > t0 and grid[-1] >= min_span else 0.0
    a, b, clamped = _order_keeping_map(_map_table(t_star, lo_all, t_hi, grid, span))
    out["suggested_map"] = {"t0": t0, "t1": t1, "a": a, "b": b,
                            "fraction_clamped": clamped, "min_span_s": span}
    return out


def _end_grid(t_limit: float, step: float = 1.0) -> np.ndarray:
    """(k,) float, s: the candidate ends ``a``, ``b`` of a landscape's map, ``0`` to
    ``t_limit`` every ``step`` s (the grid :func:`_achievable_summary` and
    :func:`_nearest_map` share)."""
    return np.arange(0.0, t_limit + 0.5 * step, step)


def _map_table(t_star, t_lo, t_hi, grid, span: float):
    """Every order-keeping map of the cells' times ``[min t*, max t*]`` onto ``[a, b]``, ``a``
    and ``b`` on ``grid`` (s) and ``b >= a + span``, with the fraction of cells it clamps.

    Parameters
    ----------
    t_star, t_lo, t_hi : (n,) float, s -- the cells' times and achievable ranges (``t_lo``
        ``inf`` where a cell cannot finish)

    Returns
    -------
    (k, 3) float -- ``a`` s, ``b`` s, fraction clamped (rounded to 9 digits)
    """
    t0, t1 = float(np.min(t_star)), float(np.max(t_star))
    u = (t_star - t0) / (t1 - t0) if t1 > t0 else np.zeros_like(t_star)
    maps = []  # (a, b, fraction clamped) of every map on the grid
    for a in grid:
        bs = grid[grid >= a + span - TOL.time]
        if not len(bs):
            break
        tt = a + u[None, :] * (bs - a)[:, None]                       # (nb, n)
        bad = ((tt < t_lo - TOL.time) | (tt > t_hi + TOL.time)).mean(axis=1)
        maps.append(np.c_[np.full(len(bs), a), bs, np.round(bad, 9)])
    return np.vstack(maps)


def _order_keeping_map(maps):
    """The map ``[a, b]`` to take among ``maps`` ((k, 3): a s, b s, fraction clamped): the
    widest that clamps at most ``Programming.fit_clamped_fraction``, then, among the maps at
    least ``fit_width_fraction`` as wide, the one clamping fewest (ties: the widest, then the
    earliest); when every map clamps more, the one clamping fewest (ties: the widest)."""
    a, b, bad = maps.T
    width = b - a
    ok = bad <= PROGRAMMING.fit_clamped_fraction + TOL.exact
    if ok.any():
        ok &= width >= PROGRAMMING.fit_width_fraction * width[ok].max() - TOL.time
    else:
        ok = bad <= bad.min() + TOL.exact
    i = np.flatnonzero(ok)[np.lexsort((a[ok], -width[ok], bad[ok]))[0]]
    return float(a[i]), float(b[i]), float(bad[i])


def sequenced_span(design_dir) -> float:
    """Smallest width (s) of a fitted landscape, so that sequenced parts stay apart.

    A design whose landscape is the automatic sequencing one (``design.json`` →
    ``options.sequencing.levels``, :mod:`pysolver.design.sequencing`) closes its parts in
    ``L`` steps; the fit keeps ``Sequencing.min_separation_s`` between them, i.e. a span of
    ``(L - 1) min_separation_s``.  Any other design: 0 s.

    Raises
    ------
    InputError
        ``options.sequencing.levels`` is there but not a list of whole numbers >= 0.
    """
    meta = tables.read_record(Path(design_dir) / "design.json") or {}
    seq = (meta.get("options") or {}).get("sequencing") if isinstance(meta, dict) else None
    levels = seq.get("levels") if isinstance(seq, dict) else None
    if not levels:
        return 0.0
    try:
        lv = np.asarray(levels, float)
    except (TypeError, ValueError):
        lv = np.array([np.nan])
    if lv.ndim != 1 or not np.all(np.isfinite(lv) & (lv >= 0) & (lv == np.round(lv))):
        raise InputError(f"{Path(design_dir) / 'design.json'}: options.sequencing.levels "
                         f"= {levels!r} is not a list of whole numbers >= 0",
                         fix="re-run the design stage")
    return float(SEQUENCING.min_separation_s * lv.max())


def _fix_message(ach) -> str:
    m = ach.get("suggested_map")
    if m is None:
        return ("no cell can finish within the bracket model's time range with "
                f"{UNIT_CELL.thickness_min:.2f}-{UNIT_CELL.thickness_max:.2f} mm brackets; "
                "check the material model.")
    rng = ach["common"]
    msg = ("shift or scale the time landscape into the achievable range: "
           + (f"every cell that can finish at all can do so between {rng[0]:.1f} and "
              f"{rng[1]:.1f} s; "
              if rng is not None else "no single time suits every cell; ")
           + f"cells can finish between {ach['earliest']:.1f} and {ach['latest']:.1f} s "
           f"overall, and {100 * ach['best_constant'][1]:.0f} % of them at "
           f"{ach['best_constant'][0]:.0f} s. ")
    if m["t1"] > m["t0"]:
        msg += (f"Mapping the landscape's {m['t0']:.1f}-{m['t1']:.1f} s linearly onto "
                f"{m['a']:.0f}-{m['b']:.0f} s, t' = {m['a']:.0f} + "
                f"{(m['b'] - m['a']) / (m['t1'] - m['t0']):.3g} * (t - {m['t0']:.1f}), "
                f"clamps {100 * m['fraction_clamped']:.0f} % of the cells")
    else:
        msg += (f"A constant {m['a']:.0f} s clamps {100 * m['fraction_clamped']:.0f} % of the "
                "cells")
    return msg + "."


def membrane_factors(design_dir, cells, membrane, correction: str = DEFAULT_CORRECTION,
                     rim=None):
    """Per-cell factors on ``F_mem`` for a correction rule (:data:`CORRECTIONS`).

    Returns
    -------
    factor : (n_cells,) float
    info : dict -- rule, FEM contraction and mesh size, factor ranges
    """
    if correction not in CORRECTIONS:
        raise InputError(f"correction={correction!r} is not a membrane correction rule.",
                         fix=f"use one of {', '.join(CORRECTIONS)}.")
    bnd = np.asarray(cells["boundary"], bool)
    info: dict = {"correction": correction}
    if correction == "boundary":
        f = np.where(bnd, membrane.boundary_factor, 1.0)
        info["boundary_factor"] = float(membrane.boundary_factor)
        return f, info

    folder = Path(design_dir)
    V, UV, F = read_stencil(folder / "stencil.obj")
    b0 = np.asarray(cells["bracket_length_mm"], float)
    _, d1 = target_compressions(b0, cells["collision_length_top_mm"],
                                cells["collision_length_bottom_mm"])
    try:
        # the simulator's bracket nodes (model.npz) when the design wrote them, so that the
        # correction meshes the very membrane the simulator will step
        geometry = None
        if (folder / tables.MODEL_FILE).is_file():
            geometry = tables.read_model(folder, n_vertices=len(V), n_faces=len(F),
                                         n_cells=len(b0), params=tables.read_unit_cell(folder))
        r = cell_membrane_factors(UV, F, cells, b0, d1, membrane, rim=rim, geometry=geometry)
    except (InputError, RuntimeError, ValueError) as e:
        # the FEM on this stencil failed (degenerate boundary geometry): the paper's rule
        info.update({"fallback": "boundary", "reason": f"{type(e).__name__}: {e}",
                     "boundary_factor": float(membrane.boundary_factor)})
        return np.where(bnd, membrane.boundary_factor, 1.0), info
    fem = r["factor"]
    # with the rim modelled (issue #18) the FEM factor replaces the paper's 0.6 cap
    f = fem if rim is not None else np.where(bnd, np.minimum(membrane.boundary_factor, fem),
                                             fem)
    if rim is not None:
        info["rim"] = {"margin_mm": float(rim[0]), "stretch": float(rim[1])}
    info.update({"fem_contraction": r["s"], "fem_triangles": r["n_triangles"],
                 "factor_range_interior": [float(fem[~bnd].min()), float(fem[~bnd].max())]
                 if (~bnd).any() else None,
                 "factor_range_boundary": [float(fem[bnd].min()), float(fem[bnd].max())]
                 if bnd.any() else None})
    return f, info


def both_layers_latest(cells: dict, factor, closing, material=None) -> np.ndarray:
    """The latest completion time (s) that *both* layers of each cell reach, each at its
    thickest bracket: the time the design stage's closed-form estimate
    (``StencilSearch.timing_slowest``) was fitted to.  ``cells.csv``'s ``t_max_s`` is the
    later layer's latest time instead (:func:`~pysolver.temporal.cell_time.time_ranges`).

    Parameters
    ----------
    cells : dict of arrays -- ``cells.csv``
    factor : (n,) float -- the per-cell F_mem factor the program stage used
        (``temporal.json`` → ``membrane_factor``)
    closing : (n, 2) float, mm -- :func:`closing_lengths`
    material : path-like or None -- the bracket material (default: the project's)

    Returns
    -------
    (n,) float, s
    """
    b0 = np.asarray(cells["bracket_length_mm"], float)
    closing = np.asarray(closing, float)
    x, d1 = target_compressions(b0, closing[:, 0], closing[:, 1])
    _, fb = bracket_target_force(load_membrane_model(), b0, d1, cells["boundary"],
                                 factor=np.asarray(factor, float))
    return time_ranges(load_material(material), b0, x, fb)[3].min(axis=1)


def closing_lengths(design_dir, cells: dict, physics=None) -> np.ndarray:
    """Bracket length at which every cell's layers close, as the simulator closes them.

    The target's collision lengths (``cells.csv``), less the printed bumpers' clearance
    (:func:`pysolver.mechanics.bumper_clearance`) when ``physics.clearance`` is on.

    Parameters
    ----------
    design_dir : path-like -- design folder (``bumpers.csv``, ``design.json``)
    cells : dict of arrays -- ``cells.csv``
    physics : PhysicsOptions, optional -- default :data:`~pysolver.params.PHYSICS_DEFAULT`

    Returns
    -------
    (c, 2) float, mm -- per cell and layer (top, bottom)
    """
    physics = PHYSICS_DEFAULT if physics is None else physics
    closing = np.c_[cells["collision_length_top_mm"], cells["collision_length_bottom_mm"]]
    if physics.clearance:
        closing = closing - bumper_clearance(tables.read_table(design_dir, "bumpers"), cells,
                                             tables.read_unit_cell(design_dir))
    return closing


def program_design(design_dir, *, material=None, membrane=None, progress: bool = True,
                   correction: str = DEFAULT_CORRECTION, t_request=None,
                   picture: bool = True, fit_landscape: bool = False, physics=None,
                   robust=None) -> dict:
    """Set the bracket thicknesses of a design folder from its time landscape.

    Reads ``cells.csv`` and ``time_landscape.csv``; sets the temporal stage's columns of
    ``cells.csv`` (:data:`pysolver.tables.LATER_CELL_COLUMNS`), writes ``temporal.json`` and
    draws ``temporal_feasibility.png``.

    Parameters
    ----------
    design_dir : path-like
        Design folder (``docs/design-folder.md``).
    material : path-like or bracket model, optional
        Bracket model (default: the committed one).
    membrane : path-like or MembraneModel, optional
        Membrane model (default: the committed ``pysolver/data/membrane_model.json``).
    correction : {"boundary", "fem"}
        Per-cell adaptation of ``F_mem`` (:data:`CORRECTIONS`); reused by :func:`refine_design`.
    t_request : (n_cells,) float, s, optional
        Program these times instead of ``t*`` (used by :func:`refine_design`).
    picture : bool
        Draw the feasibility picture.
    physics : PhysicsOptions, optional
        The simulator's physics (default :data:`~pysolver.params.PHYSICS_DEFAULT`).  With
        ``rim`` on, the ``F_mem`` correction meshes the latex margin kept at the rim (as the
        simulator does with the same option) and uses its FEM factor on boundary cells
        instead of the paper's 0.6 cap; with ``clearance`` on, each layer is programmed to
        close at the printed bumpers' contact length
        (:func:`pysolver.mechanics.bumper_clearance`), as the simulator closes it.
    robust : bool, optional
        :func:`robust_layers` (default ``Programming.robust``); the refinement follows it.
    fit_landscape : bool
        Map the landscape (order kept) when it clamps too many cells or its order would not
        show through a print's scatter (:func:`_fit_landscape`); rewrite the landscape file.
        Only a shape's *default* landscape (it gives the order in which regions finish; the
        seconds depend on the material model); a user's is never changed, only checked.
        An automatic sequencing landscape keeps its parts apart (:func:`sequenced_span`).

    Returns
    -------
    summary : dict
        ``n_cells``, ``thickness_range_mm`` (per layer), ``fraction_clamped``,
        ``clamped_cells``, ``too_early_cells``, ``too_late_cells``, ``feasible``,
        ``achievable_range_s``, ``t_star_range_s``, ``membrane_model``,
        ``boundary_factor``, ``picture``.

    Raises
    ------
    InputError
        More than half of the cells cannot reach their time (the message names the
        achievable range); missing or inconsistent tables.

    Examples
    --------
    On the ``folder`` of :func:`pysolver.design.run_design`'s example:

    >>> from pysolver.temporal import program_design
    >>> p = program_design(folder, progress=False)
    >>> p["n_cells"], [0.30 <= h <= 0.65 for h in p["thickness_range_mm"]["top"]]
    (8, [True, True])
    """
    t0 = time.perf_counter()
    design_dir = Path(design_dir)
    mat = load_material(material)  # model files first: a bad file is refused before any work
    check_bracket_geometry(mat, tables.read_unit_cell(design_dir))
    mem = load_membrane_model(membrane)
    cells = tables.read_table(design_dir, "cells")
    land = tables.read_table(design_dir, "time_landscape")["time_s"]
    models, finfo = _models(design_dir, cells, mat, mem, correction, physics, robust)
    min_span = sequenced_span(design_dir) if fit_landscape else 0.0
    p = Programme.solve(cells, land, models, t_request, min_span)
    rescaled = None
    if fit_landscape and t_request is None:
        land, p, rescaled = _fit_landscape(design_dir, cells, land, p, models, min_span, progress)
    summary = p.summary(cells, mat, mem, finfo, refined=t_request is not None, rescaled=rescaled)
    if picture and p.n:
        png = plot_feasibility(design_dir, land, p.t_star, cells, p.res, design_dir / PICTURE)
        summary["picture"] = png.name
    if not summary["feasible"]:
        p.refuse(mat, design_dir)
    summary["seconds"] = round(time.perf_counter() - t0, 3)
    p.write(design_dir, cells, summary, models[2])
    h = p.res["thickness"]
    _log(f"{design_dir.name}: {p.n} cells, thickness {h.min():.3f}-{h.max():.3f} mm, "
         f"{len(p.clamped)} clamped ({100 * p.frac:.1f} %)", progress)
    return summary


def _models(design_dir: Path, cells, mat, mem, correction: str, physics, robust=None):
    """What the cells are programmed with, for :meth:`Programme.solve`: ``(material,
    membrane, factor, closing, robust)`` -- the per-cell ``F_mem`` factor
    (:func:`membrane_factors`, with the rim margin when ``physics.rim``), the layers' closing
    lengths (:func:`closing_lengths`) and whether the layers are programmed against the
    thickness scatter (:func:`robust_layers`); and the factor's record."""
    physics = PHYSICS_DEFAULT if physics is None else physics
    robust = PROGRAMMING.robust if robust is None else bool(robust)
    rim = (physics.rim_margin_mm, physics.rim_stretch) if physics.rim else None
    factor, finfo = membrane_factors(design_dir, cells, mem, correction, rim=rim)
    return (mat, mem, factor, closing_lengths(design_dir, cells, physics), robust), finfo


def sd_list(sd) -> list:
    """Per-cell sds (s) as JSON: None where not finite."""
    return [float(v) if np.isfinite(v) else None for v in np.asarray(sd, float)]


def _sd_stats(sd) -> dict:
    sd = np.asarray(sd, float)
    ok = np.isfinite(sd)
    return {"mean": float(sd[ok].mean()) if ok.any() else None,
            "max": float(sd[ok].max()) if ok.any() else None,
            "thickness_sd_mm": UNCERTAINTY.thickness_sd}


def _fit_landscape(design_dir: Path, cells, land, p, models, min_span: float, progress: bool):
    """Map a shape's default landscape linearly (order kept) by the map that moves the cells'
    times least among those that clamp at most ``Programming.fit_clamped_fraction`` of the
    cells and keep its order visible (:func:`_nearest_map`; when every map clamps more, the
    one clamping fewest), when that clamps fewer than it does now; rewrite
    ``time_landscape.csv`` and programme the cells again from it as the file keeps it (9
    significant digits: what a rerun of the folder programmes, bit for bit).  A landscape
    that already clamps at most ``fit_clamped_fraction`` (and is at least ``min_span`` wide,
    s) is kept as given: its times are the shape's, and a map would trade them for a few
    cells (``Programming.fit_clamped_fraction``) -- unless its order would not survive a
    print's timing scatter (:func:`_order_shows`): then it is stretched about its middle,
    just enough (:func:`_spreading_map`), when that clamps at most ``fit_clamped_fraction``.

    Parameters
    ----------
    models : (material, membrane, factor, closing, robust) -- as for :meth:`Programme.solve`

    Returns
    -------
    land : (n_vertices,) float, s -- the landscape (mapped, as stored; or as it was)
    p : Programme -- for that landscape
    rescaled : dict or None -- ``from_s``, ``to_s``, ``min_span_s`` when mapped
    """
    if not len(p.t_star):
        return land, p, None  # (no cell: nothing to fit)
    m = p.ach.get("suggested_map")
    within_bar = (p.frac <= PROGRAMMING.fit_clamped_fraction + TOL.exact
                  and np.ptp(land) >= min_span - TOL.time)
    if within_bar and not _order_shows(p):
        m = _spreading_map(cells, land, p, models, min_span)
    elif m is None or m["fraction_clamped"] >= p.frac or within_bar:
        return land, p, None
    else:
        m = _nearest_map(cells, land, p, models, m) or m
    if m is None:
        return land, p, None
    t_old = (float(land.min()), float(land.max()))
    write_landscape(design_dir, _mapped_landscape(land, m))
    # programme the landscape as the file keeps it (9 significant digits), the input a rerun
    # of this folder reads: the map in memory gave t* and thicknesses 1e-9 apart from a rerun's
    land = tables.read_table(design_dir, "time_landscape")["time_s"]
    p = Programme.solve(cells, land, models, None, min_span)
    rescaled = {"from_s": list(t_old), "to_s": [float(land.min()), float(land.max())],
                "min_span_s": m["min_span_s"]}
    _log(f"default time landscape {t_old[0]:.0f}-{t_old[1]:.0f} s mapped onto the "
         f"achievable {rescaled['to_s'][0]:.0f}-{rescaled['to_s'][1]:.0f} s "
         + (f"(at least {min_span:.0f} s wide: sequenced parts "
            f"{SEQUENCING.min_separation_s:g} s apart) " if min_span else "")
         + f"({100 * p.frac:.0f} % of cells clamped)", progress)
    return land, p, rescaled


def _spreading_map(cells, land, p, models, min_span: float):
    """The narrowest map (order kept, about the middle of the cells' times) under which the
    order of a landscape shows through a print's timing scatter (:func:`_order_shows`), as a
    map of :func:`_achievable_summary`; None when no such map clamps at most
    ``Programming.fit_clamped_fraction``.

    The times are stretched by ``f = k sd / sd(t*)`` about the middle of ``[min t*, max
    t*]`` (shifted to stay within 0 s and the model's time range); ``sd`` (the RMS predicted
    sd) is that of the stretched programme, so ``f`` is re-estimated
    ``Programming.fit_order_rounds`` times."""
    t0, t1 = float(p.t_star.min()), float(p.t_star.max())
    mid, spread, q, m = 0.5 * (t0 + t1), float(np.std(p.t_star)), p, None
    if spread <= 0.0:
        return None
    for _ in range(PROGRAMMING.fit_order_rounds):
        f = max(1.0, _order_spread(q) / spread)
        a, b = mid + f * (t0 - mid), mid + f * (t1 - mid)
        shift = max(0.0, -a) - max(0.0, b - p.t_limit)
        m = {"t0": t0, "t1": t1, "a": a + shift, "b": b + shift, "min_span_s": min_span}
        q = Programme.solve(cells, _mapped_landscape(land, m), models, None, min_span)
    ok = q.frac <= PROGRAMMING.fit_clamped_fraction + TOL.exact
    return dict(m, fraction_clamped=q.frac) if ok else None


def _nearest_map(cells, land, p, models, suggested: dict):
    """The order-keeping map of a landscape that clamps too many cells which changes the
    cells' times least (RMS over cells) among the maps that clamp at most
    ``Programming.fit_clamped_fraction`` and under which its order shows through a print's
    timing scatter (:func:`_order_shows`); None when no map clamps so few.

    The maps are ``suggested``'s (:func:`_achievable_summary`: its ``t0``, ``t1``,
    ``min_span_s``, :func:`_end_grid`).  The order test needs the programme of a map (the
    predicted sd moves with the times): the nearest map wide enough for the sd of the
    programme last solved is taken, solved, and the test repeated, at most
    ``Programming.fit_order_rounds`` more times; when no map is wide enough, or the rounds
    run out, the last map taken is returned (the widest of those that clamp so few when none
    is wide enough), whose order may then not show.
    """
    t0, t1, span = suggested["t0"], suggested["t1"], suggested["min_span_s"]
    if t1 <= t0:
        return None
    lo = np.where(np.isfinite(p.res["t_min"]), p.res["t_min"], np.inf)
    maps = _map_table(p.t_star, lo, p.res["t_max"], _end_grid(p.t_limit), span)
    maps = maps[maps[:, 2] <= PROGRAMMING.fit_clamped_fraction + TOL.exact]
    if not len(maps):
        return None
    a, b = maps[:, 0], maps[:, 1]
    u = (p.t_star - t0) / (t1 - t0)
    moved = (a - t0)[:, None] + u[None, :] * ((b - a) - (t1 - t0))[:, None]    # (k, n) s
    order = np.lexsort((a, -(b - a), np.sqrt(np.mean(moved ** 2, axis=1))))
    wide = (b - a)[order] * np.std(u)                                # each map's t* sd, s
    q, m = p, None
    for _ in range(PROGRAMMING.fit_order_rounds + 1):
        fits = np.flatnonzero(wide >= _order_spread(q) - TOL.time)
        i = order[fits[0] if len(fits) else int(np.argmax(wide))]
        m = {"t0": t0, "t1": t1, "a": float(a[i]), "b": float(b[i]), "min_span_s": span,
             "fraction_clamped": float(maps[i, 2])}
        q = Programme.solve(cells, _mapped_landscape(land, m), models, None, span)
        if _order_shows(q):
            break
    return m


def _order_spread(p) -> float:
    """The sd over cells (s) that the programme ``p``'s times need for their order to show
    through a print's timing scatter (:func:`_order_shows`)."""
    sd = np.asarray(p.res["t_sd_predicted"], float)
    sd = sd[np.isfinite(sd)]
    if not sd.size:
        return 0.0
    r = 2.0 * np.sin(np.pi * PROGRAMMING.fit_order_spearman / 6.0)
    return float(r / np.sqrt(1.0 - r * r) * np.sqrt(np.mean(sd ** 2)))


def _order_shows(p) -> bool:
    """Whether the order of a programme's times would survive a print's timing scatter: the
    sd over cells of ``t*`` is at least ``k`` times the RMS over cells of each cell's
    predicted completion-time sd under the per-bracket thickness scatter
    (:func:`~pysolver.temporal.cell_time.timing_sd`), ``k`` the spread over noise at which
    two jointly normal variables have the rank correlation ``Programming.fit_order_spearman``
    (``r = 2 sin(pi rho_s / 6)``, ``k = r / sqrt(1 - r^2)``).  True when no cell has a
    finite predicted sd."""
    return bool(np.std(p.t_star) >= _order_spread(p) - TOL.time)


def _mapped_landscape(land, m: dict) -> np.ndarray:
    """The landscape mapped linearly (order kept) by a suggested map of
    :func:`_achievable_summary`: ``[t0, t1]`` onto ``[a, b]`` s, never below 0."""
    span = m["t1"] - m["t0"]
    u = (land - m["t0"]) / span if span > 0 else np.zeros_like(land)
    return np.maximum(m["a"] + u * (m["b"] - m["a"]), 0.0)


@dataclass
class Programme:
    """The thicknesses of a design's cells for one landscape (:func:`program_cells`), with
    what the summary and the refusal say about them.

    Attributes
    ----------
    t_star : (n,) float, s -- the cells' programmed times, from the landscape
    res : dict -- :func:`program_cells`
    clamped : (k,) int -- cells whose t* is out of reach
    frac : float -- ``k / n``
    ach : dict -- :func:`_achievable_summary`
    t_limit : float, s -- the material model's time range (:func:`time_limit`)
    robust : bool -- layers programmed against the thickness scatter (:func:`robust_layers`)
    """

    t_star: np.ndarray
    res: dict
    clamped: np.ndarray
    frac: float
    ach: dict
    t_limit: float
    robust: bool = False

    @classmethod
    def solve(cls, cells, land, models, t_request, min_span: float) -> Programme:
        """Programme the cells for the landscape ``land`` (s per vertex).

        ``models`` = (material, membrane, factor, closing, robust): the models, membrane
        factors and ``robust`` of :func:`program_cells`, and the layers' closing lengths
        (:func:`closing_lengths`, (c, 2) mm); ``t_request`` and ``min_span`` as for
        :func:`program_cells` and :func:`_achievable_summary`.
        """
        mat, mem, factor, closing, robust = models
        t_star = cell_target_times(land, cells["vertex_a"], cells["vertex_b"])
        res = program_cells(cells["bracket_length_mm"], closing[:, 0], closing[:, 1],
                            cells["boundary"], t_star,
                            material=mat, membrane=mem, t_request=t_request, factor=factor,
                            robust=robust)
        clamped = np.flatnonzero(res["clamped"])
        n = len(t_star)
        t_limit = time_limit(mat)
        ach = _achievable_summary(t_star, res["t_min"], res["t_max"], t_limit,
                                  min_span=min_span)
        return cls(t_star, res, clamped, float(len(clamped) / n) if n else 0.0, ach, t_limit,
                   bool(robust))

    @property
    def n(self) -> int:
        return len(self.t_star)

    def summary(self, cells, mat, mem, finfo: dict, *, refined: bool, rescaled) -> dict:
        """The programming summary (``temporal.json`` → ``summary``; see
        :func:`program_design`)."""
        res, t_star, n, h = self.res, self.t_star, self.n, self.res["thickness"]
        miss = np.where(res["side"] < 0, res["t_min"] - t_star,
                        np.where(res["side"] > 0, t_star - res["t_max"], 0.0))
        miss = np.where(np.isfinite(miss), miss, self.t_limit)
        return {
            "n_cells": int(n),
            "t_star_range_s": [float(t_star.min()), float(t_star.max())] if n else None,
            "thickness_range_mm": {"top": [float(h[:, 0].min()), float(h[:, 0].max())],
                                   "bottom": [float(h[:, 1].min()), float(h[:, 1].max())]},
            "thickness_mean_mm": float(h.mean()) if n else None,
            "fraction_clamped": self.frac,
            "n_clamped": int(len(self.clamped)),
            "clamped_cells": self.clamped.tolist(),
            "too_early_cells": np.flatnonzero(res["side"] < 0).tolist(),
            "too_late_cells": np.flatnonzero(res["side"] > 0).tolist(),
            "clamp_error_s": {"mean": float(miss[res["clamped"]].mean())
                              if len(self.clamped) else 0.0,
                              "max": float(miss.max()) if n else 0.0},
            "feasible": bool(self.frac <= PROGRAMMING.max_clamped_fraction),
            "achievable_range_s": self.ach,
            "membrane_model": {"terms": list(mem.terms), "coefficients": mem.coef.tolist(),
                               "residual_rms_N": mem.residual_rms_N},
            "boundary_factor": float(mem.boundary_factor),
            "membrane_correction": finfo,
            "n_boundary_cells": int(np.sum(cells["boundary"])),
            "membrane_force_range_N": [float(res["f_cell"].min()), float(res["f_cell"].max())]
            if n else None,
            "material_model": str(getattr(mat, "path", None) or type(mat).__name__),
            "refined_times": refined,
            "landscape_rescaled": rescaled,
            "robust": self.robust,
            "timing_sd_predicted_s": _sd_stats(res["t_sd_predicted"]),
        }

    def write(self, design_dir: Path, cells: dict, summary: dict, factor) -> None:
        """The programme into ``cells.csv`` (:func:`pysolver.tables.update_cells`: ``t*``,
        thicknesses, achievable range, NaN where a cell cannot finish, and clamping), and
        ``temporal.json`` (the summary, the membrane factors, the programmed times)."""
        res, h = self.res, self.res["thickness"]
        fin = np.isfinite(res["t_min"])
        tables.update_cells(design_dir, cells, t_star_s=self.t_star, thickness_top_mm=h[:, 0],
                            thickness_bottom_mm=h[:, 1],
                            t_min_s=np.where(fin, res["t_min"], np.nan),
                            t_max_s=np.where(fin, res["t_max"], np.nan),
                            clamped=res["clamped"])
        record = {"summary": summary, "membrane_factor": [float(v) for v in factor],
                  "t_program_s": [float(v) for v in res["t_program"]],
                  PREDICTED_SD: sd_list(res["t_sd_predicted"]),
                  "robust_lead_s": [float(v) for v in res["lead"]]}
        atomic_write_text(design_dir / STAGE_FILE, json.dumps(record, indent=1) + "\n")

    def refuse(self, mat, design_dir: Path):
        """Raise the refusal of a mostly infeasible landscape, naming why and the fix."""
        res, t_star = self.res, self.t_star
        never = ~np.isfinite(res["t_min"])
        early, late = res["side"] < 0, (res["side"] > 0) & ~never
        why = [f"{k} {what}" for k, what in (
            (int(early.sum()), "would need to finish sooner than their thinnest brackets "
                               f"({UNIT_CELL.thickness_min:.2f} mm) allow"),
            (int(late.sum()), "would need to finish later than their thickest brackets "
                              f"({UNIT_CELL.thickness_max:.2f} mm) allow"),
            (int(never.sum()), "cannot finish at all within the material model's "
                               f"{time_limit(mat):.0f} s")) if k]
        raise InputError(
            f"the time landscape is mostly infeasible: {len(self.clamped)} of {self.n} cells "
            f"({100 * self.frac:.0f} %) cannot finish at their time t* (t* spans "
            f"{t_star.min():.1f}-{t_star.max():.1f} s): " + "; ".join(why) + ".",
            fix=_fix_message(self.ach) + f" See {design_dir / PICTURE}.")


# ----------------------------------------------------------------------------------------------
# closing the loop
# ----------------------------------------------------------------------------------------------


def timing_errors(t_star, t_sim, exclude=None, t_end=None) -> dict:
    """RMS / max timing error and Spearman rank correlation of simulated completion times.

    Parameters
    ----------
    t_star : (n,) float, s -- targets
    t_sim : (n,) float, s -- simulated completion (NaN = never)
    exclude : (n,) bool, optional -- cells left out of the statistics (clamped ones)
    t_end : float, s, optional -- also give ``rms_incl_never_s``, where cells that never
        complete count as finishing at ``t_end`` (a lower bound of their error).

    Returns
    -------
    dict
        ``rms_s``, ``mean_s``, ``max_abs_s`` over completed cells, ``spearman`` (t* vs
        t_sim over completed cells), ``n_used``, ``n_never``, ``n_cells`` and, with
        ``t_end``, ``rms_incl_never_s``.
    """
    from scipy.stats import spearmanr  # heavy: this scipy submodule loads only where it is used

    t_star = np.asarray(t_star, float)
    t_sim = np.asarray(t_sim, float)
    keep = np.ones(len(t_star), bool) if exclude is None else ~np.asarray(exclude, bool)
    done = keep & np.isfinite(t_sim)
    err = t_sim[done] - t_star[done]
    rho = float("nan")
    if done.sum() >= 3 and np.ptp(t_star[done]) > 0 and np.ptp(t_sim[done]) > 0:
        rho = float(spearmanr(t_star[done], t_sim[done]).statistic)
    out = {"rms_s": float(np.sqrt(np.mean(err ** 2))) if err.size else float("nan"),
           "mean_s": float(err.mean()) if err.size else float("nan"),
           "max_abs_s": float(np.abs(err).max()) if err.size else float("nan"),
           "spearman": rho, "n_used": int(done.sum()), "n_never": int((keep & ~done).sum()),
           "n_cells": int(len(t_star))}
    if t_end is not None:
        e2 = np.where(np.isfinite(t_sim), t_sim, float(t_end))[keep] - t_star[keep]
        out["rms_incl_never_s"] = float(np.sqrt(np.mean(e2 ** 2))) if e2.size else float("nan")
    return out


__all__ = ["sequenced_span", "load_material", "CORRECTIONS", "membrane_factors",
           "target_compressions",
           "bracket_target_force", "solve_thickness", "completion_time", "time_ranges",
           "program_cells", "program_design", "closing_lengths", "Programme", "timing_errors",
           "time_limit", "REFINE_LOG", "PREDICTED_SD", "sd_list", "later_layer_moments",
           "layer_sensitivity", "robust_layers", "timing_sd",
           "PICTURE", "STAGE_FILE"]
