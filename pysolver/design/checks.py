"""Printability checks of a layout: refuse unprintable designs with actionable errors.

:func:`check_layout` returns a :class:`CheckReport` (errors, warnings, figures) and, with
``raise_=True`` (default), raises :class:`~pysolver.errors.InputError` on the first
class of error, naming the cells/bases concerned and where they are in the target.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..geometry import signed_areas_2d
from ..params import LIMITS, STENCIL, UNIT_CELL, UnitCell
from ..params import tol as TOL
from .layout import Layout


@dataclass
class CheckReport:
    """Result of :func:`check_layout`."""

    errors: list = field(default_factory=list)  # list of (message, fix)
    warnings: list = field(default_factory=list)  # list of str
    figures: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.errors

    def raise_if_failed(self):
        if self.errors:
            msg = "; ".join(e[0] for e in self.errors if e[0])
            fix = " / ".join(e[1] for e in self.errors if e[1])
            raise InputError(f"unprintable design: {msg}", fix=fix or None)

    def to_dict(self) -> dict:
        return {"ok": self.ok, "errors": [e[0] for e in self.errors],
                "warnings": list(self.warnings), "figures": self.figures}


def _xyz(p) -> str:
    """``(12.3, -40.1, 5.0)``: a point in mm to 0.1 mm (no ``-0.0``)."""
    p = np.round(np.asarray(p, float), 1) + 0.0
    return f"({p[0]:.1f}, {p[1]:.1f}, {p[2]:.1f})"


def _where(P: np.ndarray, frame: str = "on the target") -> str:
    return f"around {_xyz(P.mean(axis=0))} mm {frame}"


def _region(P: np.ndarray, on_rim: np.ndarray) -> str:
    """Where a set of items lies: centre and radius of the set, and whether it hugs the rim.

    Parameters
    ----------
    P : (k, 3) float, mm -- item positions
    on_rim : (k,) bool -- item touches a boundary base
    """
    c = P.mean(axis=0)
    r = float(np.linalg.norm(P - c, axis=1).max(initial=0.0))
    s = f"region centred at {_xyz(c)} mm, radius {r:.1f} mm"
    nb = int(np.sum(on_rim))
    if nb * 2 >= len(P):
        s += f", mostly along the rim ({nb} of {len(P)} next to the boundary)"
    else:
        s += f", mostly inside ({len(P) - nb} of {len(P)} away from the boundary)"
    return s


def _worst(ids, pos, score, k=4) -> str:
    """``id at (x, y, z)`` for the k worst items (highest score), + how many in all."""
    ids = np.asarray(ids)
    order = ids[np.argsort(-score[ids], kind="stable")]
    parts = [f"{int(i)} at {_xyz(pos[i])} mm" for i in order[:k]]
    return "; ".join(parts) + (f"; ... ({len(ids)} in all)" if len(ids) > k else "")


def _ids(ids, k=8) -> str:
    ids = [int(i) for i in ids]
    s = ", ".join(map(str, ids[:k]))
    return s + (f", ... ({len(ids)} in all)" if len(ids) > k else "")


def bumper_contact_errors(lay: Layout):
    """3D contact of facing bumpers in the target.

    For every cell and layer, the two bumpers' far-face tip points (on their ideal
    planes, before clearance) are compared: ``normal`` = distance between the tips
    along the bisector normal (0 = touching), ``lateral`` = in-plane offset of the tips.

    Returns
    -------
    normal : (c, 2) float, mm
    lateral : (c, 2) float, mm
    """
    b = lay.bumpers
    c = len(lay.cells.faces)
    normal = np.zeros((c, 2))
    lateral = np.zeros((c, 2))
    for s in (0, 1):
        sel = np.flatnonzero(b.layer == s)
        cell, base = b.cell[sel], b.base[sel]
        first = np.full(c, -1)
        second = np.full(c, -1)
        is_a = base == lay.cells.faces[cell, 0]
        first[cell[is_a]] = sel[is_a]
        second[cell[~is_a]] = sel[~is_a]
        ta, tb = b.tip_t[first], b.tip_t[second]
        m = b.bis_n_t[first]
        normal[:, s] = np.abs(np.sum((tb - ta) * m, axis=1))
        dv = tb - ta
        lateral[:, s] = np.linalg.norm(dv - np.sum(dv * m, 1)[:, None] * m, axis=1)
    return normal, lateral


def check_layout(lay: Layout, params: UnitCell = UNIT_CELL, *, raise_: bool = True,
                 to_input=None) -> CheckReport:
    """Check a layout for printability.

    Errors: cells longer than ``max_cell_length``; bases or bumpers closer than
    ``min_gap`` in the flat layout (or overlapping); flipped flat triangles.
    Warnings: cells near the length limit or beyond the bracket-model grid, short
    concave-side bumpers, faces with two boundary edges.

    Parameters
    ----------
    lay : Layout
    params : UnitCell
    raise_ : bool
        Raise InputError when there are errors.
    to_input : callable((k, 3) float) -> (k, 3) float, optional
        Maps target-frame points (the layout's centred, scaled ``V``, mm) to other
        coordinates named in the messages.  By default messages give mm on the target
        (``stencil.obj`` v: the input after ``--scale``/``--size``, centred and scaled by
        the 3D rule), e.g. "at (12.3, -40.1, 5.0) mm on the target".
    """
    rep = CheckReport()
    l = lay.central_length
    frame = "on the target"
    Fc = lay.Fc
    if to_input is not None:
        Fc = np.asarray(to_input(Fc), float)
        frame = "in the input's coordinates"
    # 1. flips in the flattening
    A = signed_areas_2d(lay.UV, lay.F)
    flipped = np.flatnonzero(A <= 0)
    if len(flipped):
        rep.errors.append((
            f"{len(flipped)} flipped triangle(s) in the flat layout (faces {_ids(flipped)}, "
            f"{_where(Fc[flipped], frame)})",
            "use flattening='cetm', improve the mesh quality there, or cut the surface"))
    too_long, near = _check_lengths(rep, lay, params, Fc, frame)      # 2. cell length
    _check_gaps(rep, lay, params, Fc, frame)                          # 3. flat gaps
    _check_bumpers(rep, lay, params)                                  # 4. bumpers
    # 5. topology hints
    two_bnd = np.flatnonzero(np.sum(lay.ff < 0, axis=1) >= 2)
    if len(two_bnd):
        rep.warnings.append(f"{len(two_bnd)} base(s) with two boundary edges (loosely held): "
                            f"{_ids(two_bnd)}")
    rep.figures.update(
        max_cell_length_mm=float(l.max()), min_cell_length_mm=float(l.min()),
        n_cells_over_limit=int(len(too_long)), n_cells_near_limit=int(len(near)),
        n_flipped=int(len(flipped)))
    if raise_:
        rep.raise_if_failed()
    return rep


def _check_lengths(rep: CheckReport, lay: Layout, params: UnitCell, Fc, frame: str):
    """Cells longer than the limit (errors), near it or beyond the bracket model's measured
    lengths (warnings).  Returns the ids of the cells over and near the limit."""
    cells, l = lay.cells, lay.central_length
    cell_pos = 0.5 * (Fc[cells.faces[:, 0]] + Fc[cells.faces[:, 1]])
    rim_face = np.any(lay.ff < 0, axis=1)
    cell_rim = rim_face[cells.faces[:, 0]] | rim_face[cells.faces[:, 1]]
    too_long = np.flatnonzero(l > params.max_cell_length)
    if len(too_long):
        rep.errors.append((
            f"{len(too_long)} unit cell(s) longer than {params.max_cell_length} mm (max "
            f"{l.max():.2f} mm), {frame}: cell {_worst(too_long, cell_pos, l)}; "
            f"{_region(cell_pos[too_long], cell_rim[too_long])}",
            "the surface needs too much stretching or bending there: cut the surface "
            "through that region or reduce its curvature; the stencil's irregularity also "
            "matters: try another vertex count (--vertices N) or CVT seed (Python: "
            "vertices=N, seed=k)"))
    near_fraction = STENCIL.near_limit_fraction
    near = np.flatnonzero((l > near_fraction * params.max_cell_length)
                          & (l <= params.max_cell_length))
    if len(near):
        rep.warnings.append(f"{len(near)} cell(s) within {100 * (1 - near_fraction):.0f}% of the "
                            f"{params.max_cell_length} mm length limit: cells {_ids(near)}")
    l_model = LIMITS.model_max_central_length_mm
    beyond = np.flatnonzero((l > l_model) & (l <= params.max_cell_length))
    if len(beyond):
        rep.warnings.append(f"{len(beyond)} cell(s) longer than {l_model} mm "
                            "(beyond the measured bracket grid; the model extrapolates): "
                            f"cells {_ids(beyond)}")
    return too_long, near


def _check_gaps(rep: CheckReport, lay: Layout, params: UnitCell, Fc, frame: str) -> None:
    """Bases or bumpers closer than ``min_gap`` in the flat layout, or overlapping."""
    gaps = lay.gaps
    if gaps is None or not len(gaps.gap):
        return
    bad = np.flatnonzero(gaps.gap < params.min_gap - TOL.gap)
    if len(bad):
        pairs = gaps.pairs[bad]
        over = np.flatnonzero(gaps.gap[bad] <= 0)
        kind = "overlap" if len(over) else f"are closer than {params.min_gap} mm"
        mid = 0.5 * (Fc[pairs[:, 0]] + Fc[pairs[:, 1]])
        where = "; ".join(f"bases {a}-{b} ({g:.3f} mm) at {_xyz(m)} mm {frame}"
                          for (a, b), g, m in
                          zip(pairs[:4], gaps.gap[bad][:4], mid[:4], strict=True))
        rep.errors.append((
            f"{len(bad)} pair(s) of bases/bumpers {kind} in the flat layout (min gap "
            f"{gaps.gap.min():.3f} mm): {where}",
            "the flattening folds or squeezes that region: cut the surface there or "
            "reduce its curvature"))
    rep.figures["min_flat_gap_mm"] = float(gaps.gap.min())


def _check_bumpers(rep: CheckReport, lay: Layout, params: UnitCell) -> None:
    """Short concave-side bumpers (warning) and the bumpers' contact figures."""
    b = lay.bumpers
    straight = b.cut == "straight"
    beyond_rim = b.length - params.base_r
    if np.any(straight):
        short = np.flatnonzero(straight & (beyond_rim < params.min_bumper - 0.01))
        if len(short):
            rep.warnings.append(
                f"{len(short)} concave-side bumper(s) stick out less than {params.min_bumper} "
                f"mm beyond the base (min {beyond_rim[short].min():.3f} mm; asymmetric cells)")
    normal, lateral = bumper_contact_errors(lay)
    rep.figures["bumper_contact_normal_max_mm"] = float(normal.max())
    rep.figures["bumper_contact_lateral_max_mm"] = float(lateral.max())
    rep.figures["min_bumper_beyond_rim_mm"] = float(beyond_rim.min())


__all__ = ["CheckReport", "check_layout", "bumper_contact_errors"]
