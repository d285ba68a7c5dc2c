"""Printable unit-cell test specimens (issue #9): the bracket grid of Supplementary Note 3.

Each specimen is one unit cell of central length ``l`` and bracket thickness ``h``
made by ``specimen()`` of ``scad/specimen.scad``, which uses the shells' own
``base()`` and ``bracket()`` modules (an edit of the bracket module changes the
specimens too).  A specimen is two half-cells stacked with a 0.05 mm gap, like
the two layers of a shell around the membrane; each half has two bases, the full
bracket rhombus and a 40 x 5 mm handle pair; pins of the lower half pass through
holes of the upper half.  Labels ``L<l>`` / ``H<h>`` are raised on the top face
and engraved in the bed face, in a seven-segment font drawn by the library (no
system font involved).

``make_specimens`` renders every specimen through the render stage's part cache
and OpenSCAD pool and lays them out on build plates.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from ..core.staging import atomic_dir
from ..core.writes import atomic_write_text
from ..errors import InputError
from ..params import UNIT_CELL
from .parts import default_cache_dir, render_parts
from .scad_io import SCAD_DIR, Part, check_library, part_text
from .solids import describe_stl, from_manifold, load_stl, to_manifold, union

AUTHORS_THICKNESSES_SHORT = (0.30, 0.40, 0.50, 0.60)
"""mm: bracket thicknesses of the authors' specimen grid for l <= 7 mm."""
AUTHORS_THICKNESSES_LONG = (0.35, 0.45, 0.55, 0.65)
"""mm: bracket thicknesses of the authors' specimen grid for l > 7 mm."""

SPECIMEN_LENGTH = 40.0
"""mm: overall specimen length (``SPEC_LENGTH`` in ``scad/specimen.scad``)."""
MAX_SPECIMEN_L = SPECIMEN_LENGTH - 4 * UNIT_CELL.base_r - 4 * 4.0
"""mm: longest central length that leaves room for the handles' pins (the SCAD assert)."""

PLATE_SPACING = 3.0
"""mm: clearance between specimens on a build plate."""


def specimen_grid(lengths=(5, 6, 7, 8, 9), thicknesses=None) -> list[tuple[float, float]]:
    """The (l, h) pairs to print.

    Parameters
    ----------
    lengths : sequence of float, mm
        Central lengths (base-centre distances).
    thicknesses : sequence of float, mm, optional
        Bracket thicknesses for every length.  Default: the authors' grid,
        0.30/0.40/0.50/0.60 for l <= 7 mm and 0.35/0.45/0.55/0.65 for l > 7 mm.

    Returns
    -------
    grid : list of (l, h), in the order lengths x thicknesses, without repeats

    Raises
    ------
    InputError
        A length or thickness cannot be printed as a specimen.
    """
    lengths = [float(v) for v in np.atleast_1d(lengths)]
    if not lengths:
        raise InputError("no specimen lengths given.", fix="pass e.g. lengths=(5, 6, 7, 8, 9).")
    grid = []
    for l in lengths:
        if not (UNIT_CELL.bracket_offset < l <= MAX_SPECIMEN_L):
            raise InputError(
                f"specimen central length {l} mm is outside ({UNIT_CELL.bracket_offset:.3f}, "
                f"{MAX_SPECIMEN_L:g}] mm.",
                fix="bases overlap below 2 base_r cos(37 deg); the 40 mm specimen has no room "
                    "for handles above that maximum.")
        hs = thicknesses
        if hs is None:
            hs = AUTHORS_THICKNESSES_SHORT if l <= 7 else AUTHORS_THICKNESSES_LONG
        for h in np.atleast_1d(hs):
            h = float(h)
            if not (0 < h < UNIT_CELL.bracket_w):
                raise InputError(f"bracket thickness {h} mm must be in (0, "
                                 f"{UNIT_CELL.bracket_w}) mm (thinner than the bracket height).",
                                 fix="the paper's brackets are "
                                     f"{UNIT_CELL.thickness_min:.2f}-"
                                     f"{UNIT_CELL.thickness_max:.2f} mm thick.")
            if (l, h) not in grid:
                grid.append((l, h))
    return grid


def specimen_name(l: float, h: float) -> str:
    """File stem of a specimen, e.g. ``specimen_l7_h0.45``."""
    return f"specimen_l{l:g}_h{h:g}"


def plate_layout(sizes, build_area, spacing: float = PLATE_SPACING) -> list[list[tuple]]:
    """Shelf packing of rectangles onto as many plates as needed, in the given order.

    Parameters
    ----------
    sizes : (n, 2) float, mm
        Footprint (x, y extent) of each item.
    build_area : (2,) float, mm
        Plate size (x, y).
    spacing : float, mm
        Clearance between neighbouring items.

    Returns
    -------
    plates : list of list of (index, x, y)
        Per plate, the items with the position of their footprint's lower-left
        corner; every footprint lies inside [0, X] x [0, Y].

    Raises
    ------
    InputError
        An item is larger than the build area.
    """
    W, H = (float(v) for v in build_area)
    plates: list[list[tuple]] = [[]]
    x = y = row_h = 0.0
    for i, (w, d) in enumerate(np.asarray(sizes, float)):
        if w > W or d > H:
            raise InputError(f"a specimen ({w:.1f} x {d:.1f} mm) does not fit the build area "
                             f"{W:g} x {H:g} mm.", fix="give a larger build_area.")
        if x > 0 and x + w > W:               # next shelf
            x, y, row_h = 0.0, y + row_h + spacing, 0.0
        if y + d > H:                         # next plate
            plates.append([])
            x = y = row_h = 0.0
        plates[-1].append((i, x, y))
        x += w + spacing
        row_h = max(row_h, d)
    return plates


def make_specimens(out_dir, lengths=(5, 6, 7, 8, 9), thicknesses=None, build_area=(200, 200),
                   jobs=None, *, scad_dir=None, cache_dir=None, progress: bool = True,
                   renderer=None) -> dict:
    """Render unit-cell specimens and their build-plate layout.

    Parameters
    ----------
    out_dir : path-like
        Output folder: ``scad/`` (part files), ``stl/specimen_l<l>_h<h>.stl``
        (each in its own frame: bed z = 0, cell axis along x, centred),
        ``stl/plate_<k>.stl`` (the specimens laid out on plate k, inside
        [0, X] x [0, Y]) and ``specimens.csv``.
    lengths : sequence of float, mm
        Central lengths l.
    thicknesses : sequence of float, mm, optional
        Bracket thicknesses h for every l (default: the authors' grid, see
        :func:`specimen_grid`).
    build_area : (2,) float, mm
        Printer build plate (x, y).
    jobs : int, optional
        Parallel OpenSCAD processes (default: CPU count).
    scad_dir : path-like, optional
        OpenSCAD library (default: the repository's ``scad/``).
    cache_dir : path-like, optional
        Part cache (default: ``build/.cache/parts`` above ``out_dir``, else beside it).
    progress : bool
        Progress bar on stderr.
    renderer : {"openscad", "fast", "auto"}, optional
        Part renderer (default :data:`pysolver.render.DEFAULT_RENDERER`), see
        :func:`pysolver.render.render_parts`.

    Returns
    -------
    summary : dict
        ``count``, ``specimens`` (list of dicts: l_mm, h_mm, labels, stl, plate,
        plate_xy_mm, bbox_mm, watertight, bodies, volume_mm3), ``plates``
        (list of dicts: stl, count, bbox_mm, watertight, bodies), ``rendered``,
        ``cached``, ``seconds_per_part``, ``timings_s``.
    """
    t_start = time.perf_counter()
    grid = specimen_grid(lengths, thicknesses)
    if len(build_area) != 2 or min(build_area) <= 0:
        raise InputError(f"build_area must be (x, y) in mm, got {build_area!r}.",
                         fix="e.g. build_area=(200, 200).")
    out_dir = Path(out_dir)
    scad_dir = check_library(Path(scad_dir).resolve() if scad_dir else SCAD_DIR)
    cache_dir = Path(cache_dir) if cache_dir else default_cache_dir(out_dir)
    lib = scad_dir / "specimen.scad"
    with atomic_dir(out_dir / "scad") as tmp:
        for l, h in grid:
            name = specimen_name(l, h)
            (tmp / f"{name}.scad").write_text(
                part_text(f"{name}: unit-cell specimen l = {l:g} mm, h = {h:g} mm", lib,
                          "specimen", l=l, h=h), newline="\n")
    parts = [Part(specimen_name(l, h), "specimen", None, -1,
                  out_dir / "scad" / f"{specimen_name(l, h)}.scad") for l, h in grid]
    res = render_parts(parts, cache_dir=cache_dir, scad_dir=scad_dir, jobs=jobs,
                       progress=progress, renderer=renderer)

    t0 = time.perf_counter()
    solids = [to_manifold(load_stl(res["stl"][p.name]), f"specimen {p.name}") for p in parts]
    sizes = []
    for m in solids:
        lo, hi = (np.asarray(v, float) for v in _bbox(m))
        sizes.append(hi[:2] - lo[:2])
    plates = plate_layout(sizes, build_area)
    specs: list[dict] = [{} for _ in parts]
    plate_info = []
    with atomic_dir(out_dir / "stl") as tmp:
        for p, m, spec in zip(parts, solids, specs, strict=True):
            path = tmp / f"{p.name}.stl"
            from_manifold(m).export(str(path), file_type="stl")
            spec.update(describe_stl(path, m))
        for k, plate in enumerate(plates, start=1):
            placed = []
            for i, x, y in plate:
                lo = np.asarray(_bbox(solids[i])[0], float)
                placed.append(solids[i].translate([x - lo[0], y - lo[1], -lo[2]]))
                specs[i]["plate"] = k
                specs[i]["plate_xy_mm"] = [round(x, 6), round(y, 6)]
            m = union(placed)
            path = tmp / f"plate_{k}.stl"
            from_manifold(m).export(str(path), file_type="stl")
            info = describe_stl(path, m)
            info.update(count=len(plate), stl=str(out_dir / "stl" / path.name))
            plate_info.append(info)
    rows = ["l_mm,h_mm,label_left,label_right,stl,plate,plate_x_mm,plate_y_mm"]
    for (l, h), p, spec in zip(grid, parts, specs, strict=True):
        left, right = specimen_labels(l, h)
        spec.update(l_mm=l, h_mm=h, labels=[left, right],
                    stl=str(out_dir / "stl" / f"{p.name}.stl"))
        rows.append(f"{l:.9g},{h:.9g},{left},{right},stl/{p.name}.stl,{spec['plate']},"
                    f"{spec['plate_xy_mm'][0]:.9g},{spec['plate_xy_mm'][1]:.9g}")
    atomic_write_text(out_dir / "specimens.csv", "\n".join(rows) + "\n")
    t_layout = time.perf_counter() - t0
    n_r = res["rendered"]
    summary = {
        "count": len(parts),
        "specimens": specs,
        "plates": plate_info,
        "build_area_mm": [float(v) for v in build_area],
        "rendered": n_r,
        "cached": res["cached"],
        "seconds_per_part": (float(np.mean(list(res["seconds"].values()))) if n_r else None),
        "cpu_seconds_per_part": (res["cpu_s"] / n_r if n_r else None),
        "timings_s": {"openscad": round(res["wall_s"], 3), "layout": round(t_layout, 3),
                      "total": round(time.perf_counter() - t_start, 3)},
        "openscad": res["openscad"],
        "renderer": res["renderer"],
        "scad_dir": str(scad_dir),
        "cache_dir": str(cache_dir),
    }
    if progress:
        print(f"[specimens] {len(parts)} specimens on {len(plates)} plate(s) -> {out_dir}",
              file=sys.stderr, flush=True)
    return summary


def specimen_labels(l: float, h: float) -> tuple[str, str]:
    """Handle labels as ``specimen_labels()`` of ``scad/specimen.scad`` writes them.

    ``("L" + l, "H" + h without its leading zero)``, numbers as OpenSCAD's
    ``str()`` prints them (up to 6 significant digits), e.g. ``("L7", "H.45")``.
    """
    def fmt(v):
        return f"{v:.6g}"

    hs = fmt(h)
    if h < 1 and hs.startswith("0"):
        hs = hs[1:]
    return f"L{fmt(l)}", f"H{hs}"


def _bbox(m):
    b = m.bounding_box()
    return b[:3], b[3:]


__all__ = ["specimen_grid", "specimen_name", "specimen_labels", "plate_layout", "make_specimens",
           "AUTHORS_THICKNESSES_SHORT", "AUTHORS_THICKNESSES_LONG", "PLATE_SPACING"]
