"""``morphshell coupon``: the printable timing coupon and its table (issue #45).

The coupon is a design folder like any shell's (:func:`pysolver.design.pipeline.run_design`
on :func:`pysolver.temporal.coupon.coupon_source`), with the bracket thicknesses of
:func:`pysolver.temporal.coupon.coupon_thicknesses` given as a thickness file, rendered by the
render stage (the shells' own SCAD modules).  Its top layer is printed with each base's number
engraved in the far face (``scad/coupon.scad``), so that a cell is named by its two bases.
Beside the STLs: ``coupon.csv`` (one row per timed cell, ``closing_time_s`` to fill in) and
``coupon.md`` (how to time it; ``docs/coupon.md``) and ``coupon.png`` (the map).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from .core.progress import say
from .core.writes import atomic_file, atomic_write_text
from .design.pipeline import run_design
from .geometry import print_transform
from .params import UNIT_CELL
from .render import (
    default_cache_dir,
    describe_stl,
    from_manifold,
    load_stl,
    render_design,
    render_parts,
    to_manifold,
)
from .render.scad_io import SCAD_DIR, Part, part_text
from .tables import read_table
from .temporal import coupon as tc
from .temporal.plots import plot_coupon
from .temporal.program import load_material

SHEET = Path(__file__).resolve().parents[1] / "docs" / "coupon.md"
"""The one-page sheet, copied beside the coupon's STLs."""
PICTURE = "coupon.png"
"""The coupon's map: base numbers, each timed cell's thickness and predicted time."""
TOP_STL = "coupon_top.stl"
"""The top layer with the base numbers engraved (print it with ``stl/bottom.stl``)."""


def _thickness_file(folder: Path, cells: dict, thickness) -> Path:
    """A ``--thickness-file`` of the given thicknesses (n, 2) mm for ``cells``."""
    path = folder / "thickness.csv"
    rows = ["base_a,base_b,thickness_top_mm,thickness_bottom_mm"]
    rows += [f"{a},{b},{h[0]:.9g},{h[1]:.9g}" for a, b, h in
             zip(cells["base_a"], cells["base_b"], thickness, strict=True)]
    path.write_text("\n".join(rows) + "\n")
    return path


def base_labels(out: Path) -> list:
    """``[text, [x, y]]`` of every base: its number (base id + 1) at its flat centre (mm)."""
    bases = read_table(out, "bases")
    return [[str(int(i) + 1), [float(x), float(y)]] for i, x, y in
            zip(bases["base_id"], bases["flat_x_mm"], bases["flat_y_mm"], strict=True)]


def engrave_labels(out: Path, *, jobs=None, progress: bool = True, renderer=None) -> dict:
    """``coupon_top.stl``: the rendered top layer minus the base numbers
    (``coupon_labels()`` of ``scad/coupon.scad``, rendered through the part cache)."""
    scad = out / "scad" / "coupon_labels.scad"
    with atomic_file(scad) as tmp:
        tmp.write_text(part_text("timing coupon: base numbers", SCAD_DIR / "coupon.scad",
                                 "coupon_labels", labels=base_labels(out),
                                 height=UNIT_CELL.layer_h), newline="\n")
    part = Part("coupon_labels", "coupon_labels", "top", -1, scad)
    res = render_parts([part], cache_dir=default_cache_dir(out), jobs=jobs, progress=progress,
                       renderer=renderer)
    cut = to_manifold(load_stl(res["stl"][part.name]), "coupon labels")
    T = print_transform("top")
    cut = cut.transform(T[:3, :])
    top = to_manifold(load_stl(out / "stl" / "top.stl"), "coupon top layer")
    m = top - cut
    with atomic_file(out / TOP_STL) as tmp:
        from_manifold(m).export(str(tmp), file_type="stl")
    return describe_stl(out / TOP_STL, m)


def make_coupon(out, *, material=None, jobs=None, progress: bool = True, renderer=None,
                render: bool = True) -> dict:
    """Design, render and tabulate the timing coupon into ``out``.

    Parameters
    ----------
    out : path-like
        Output folder (new, empty, or a coupon morphshell made): a design folder with
        ``stl/``, ``coupon_top.stl``, ``coupon.csv`` and ``coupon.md``.
    material : path-like, optional
        Bracket model the thicknesses and predicted times are computed with.
    jobs, renderer : the render stage's
    render : bool
        Render the STLs (off in fast tests).

    Returns
    -------
    dict
        ``out``, ``cells`` (timed), ``thickness_range_mm``, ``predicted_range_s``, ``rows``,
        ``top`` (the labelled layer's STL description, when rendered).
    """
    out = Path(out).absolute()
    mat = load_material(material)
    with tempfile.TemporaryDirectory(prefix="morphshell-coupon-") as tmp:
        probe = Path(tmp) / "probe"
        run_design(tc.coupon_source(), probe, progress=False, plots=False)
        geom = tc.cell_geometry(probe)
        th, timed = tc.coupon_thicknesses(mat, geom)
        tfile = _thickness_file(Path(tmp), read_table(probe, "cells"), th)
        run_design(tc.coupon_source(), out, progress=progress, plots=False,
                   thickness_file=tfile)
    rows = tc.coupon_rows(geom, th, timed, mat)
    cells = read_table(out, "cells")
    for r in rows:  # the maker finds a cell by its two bases' engraved numbers
        j = r["cell_id"]
        r["label"] = f"{int(cells['base_a'][j]) + 1}-{int(cells['base_b'][j]) + 1}"
    res = {"out": str(out), "cells": len(rows), "rows": rows,
           "thickness_range_mm": [float(th[timed].min()), float(th[timed].max())],
           "predicted_range_s": [min(r["predicted_s"] for r in rows),
                                 max(r["predicted_s"] for r in rows)]}
    if render:
        render_design(out, jobs=jobs, progress=progress, actuated=False, renderer=renderer)
        res["top"] = engrave_labels(out, jobs=jobs, progress=progress, renderer=renderer)
    plot_coupon(read_table(out, "bases"), cells, rows, out / PICTURE)
    atomic_write_text(out / tc.CSV_NAME, tc.coupon_csv_text(rows))
    atomic_write_text(out / "coupon.md", SHEET.read_text())
    say("coupon", out.name, f"{len(rows)} timed cells, brackets "
        f"{res['thickness_range_mm'][0]:.2f}-{res['thickness_range_mm'][1]:.2f} mm, predicted "
        f"{res['predicted_range_s'][0]:.0f}-{res['predicted_range_s'][1]:.0f} s -> {out}",
        progress)
    return res


__all__ = ["make_coupon", "engrave_labels", "base_labels", "TOP_STL"]
