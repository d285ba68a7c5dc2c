"""The design stage: from a target surface to the design folder (tables, stencil, pictures).

:func:`run_design` is the one entry point::

    from pysolver.design import run_design
    summary = run_design("petal", "build/petal")

Stages (timed in the summary): load -> remesh -> flatten (CETM and LSCM, compared)
-> layout (scaling rules, bases, bumpers) -> nodes -> time landscape -> checks -> write
-> plots.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys
import time as _time
from dataclasses import replace
from pathlib import Path

import numpy as np

from .. import tables
from ..errors import InputError
from ..params import LIMITS, REFERENCE_MIN_BUMPER_MM, UNIT_CELL, UnitCell, check_unit_cell
from ..params import tol as TOL
from . import surfaces
from .cellnodes import bracket_nodes, collision_lengths, write_model_file
from .checks import check_layout
from .flatten import compare_flattenings, distortion_metrics
from .layout import Layout, build_layout
from .mesh_input import load_input, size_factor
from .plots import write_design_plots
from .remesh import remesh_surface, stencil_figures, surface_area
from .sequencing import sequencing_landscape
from .thickness_file import cell_thicknesses, read_thickness_file
from .time_landscape import (
    TIME_FILE_ATTRIBUTE,
    cell_target_times,
    check_time_option,
    check_time_source,
    read_time_file,
    resolve_time,
    time_file_per_vertex,
)

FLATTENINGS = ("cetm", "lscm")


class _Clock:
    def __init__(self, progress: bool, label: str):
        self.t = {}
        self.progress = progress
        self.label = label
        self._t0 = _time.perf_counter()
        self._start = self._t0

    def step(self, name: str):
        now = _time.perf_counter()
        self.t[name] = round(now - self._t0, 4)
        self._t0 = now
        if self.progress:
            print(f"[design {self.label}] {name:<10s} {self.t[name]:7.2f} s "
                  f"(total {now - self._start:6.1f} s)", file=sys.stderr, flush=True)


def _load_source(source, scale: float, size=None, stencil: bool = False):
    """Returns (surface-like object, kind, source description, hash, input mesh or None,
    factor applied to the input coordinates: ``scale``, or the one that ``size`` asks for)."""
    if isinstance(source, surfaces.Surface):
        h = hashlib.sha256(np.ascontiguousarray(source.V).tobytes()).hexdigest()[:16]
        return source, "builtin", source.name, h, None, 1.0
    src = str(source)
    p = Path(src)
    if not p.exists() and surfaces.is_builtin(src):
        if stencil:
            raise InputError(f"--stencil: {src} is a built-in shape, not a stencil OBJ",
                             fix="give the path of a stencil OBJ (v = target, vt = flat)")
        surf = surfaces.builtin(src)
        if size is not None:

            scale = size_factor(surf.V, size, src)
        if scale != 1.0:
            surf.V = surf.V * scale
            if surf.UV is not None:
                surf.UV = surf.UV * scale
            if surf.time is not None:
                t0 = surf.time
                surf.time = lambda X, t0=t0: t0(np.asarray(X) / scale)
        h = hashlib.sha256(src.encode()).hexdigest()[:16]
        return surf, "builtin", src, h, None, scale
    if not p.exists():
        raise InputError(f"{src}: no such file and not a built-in shape",
                         fix=f"give a mesh file (OBJ, STL, PLY, OFF) or one of "
                             f"{', '.join(surfaces.BUILTIN)}")

    mesh = load_input(p, scale=scale, size=size, stencil=stencil)
    h = hashlib.sha256(p.read_bytes()).hexdigest()[:16]
    surf = surfaces.Surface(p.stem, mesh.V, mesh.F, UV=mesh.UV)
    return surf, ("stencil" if mesh.UV is not None else "mesh"), str(p), h, mesh, mesh.scale


def _target_times(time, surf, mesh):
    """(n,) float, s, or None: the time landscape at the target's own vertices, before
    remeshing, so that the stencil optimisation can suit the cells' speeds to it (None when
    it is constant: programming then picks the constant itself).  Coordinates are centred on
    the target and unscaled; the final landscape sees the stencil, centred on itself and
    scaled by the 3D rule (which the count search keeps within a few per cent of 1): an
    expression of x, y, z differs by that much, which the optimisation's estimate (error
    about 25 % in time) does not feel."""
    c = np.asarray(surf.V, float).mean(axis=0)
    if time is None and surf.time is not None:
        t = resolve_time(None, surf.V - c, default=lambda X: surf.time(X + c))[0]
    else:
        src = None if mesh is None else mesh.transformed(-c, 1.0)
        t = resolve_time(time, surf.V - c, source_mesh=src)[0]
    return t if np.ptp(t) > TOL.time else None


def _time_file_source(path, mesh, surf, stencil_order: bool):
    """The ``time`` source for ``--time-file``: the values as they are (an array per stencil
    vertex) for a finished stencil, else a vertex attribute of the input mesh that
    :func:`~pysolver.design.time_landscape.resolve_time` interpolates (``vertex:<name>``).

    Returns
    -------
    time : (n,) float array or str
    info : dict -- ``path``, ``sha256``, ``values``, ``carried`` (recorded in design.json)
    """
    values, sha = read_time_file(path)
    if mesh is None:
        raise InputError(f"--time-file {path} gives values per vertex of an input mesh; "
                         f"{surf.name} is a built-in shape",
                         fix="give the time landscape of a built-in shape with --time "
                             "(an expression of x, y, z in mm), or design a mesh file")
    t = time_file_per_vertex(values, mesh, str(path))
    info = {"path": str(path), "sha256": sha, "values": int(len(values))}
    if surf.UV is not None or stencil_order:  # the stencil is the input: vertex-aligned
        info["carried"] = "used as given: the input is the stencil"
        return t, info
    mesh.vertex_attributes = dict(mesh.vertex_attributes or {}, **{TIME_FILE_ATTRIBUTE: t})
    info["carried"] = "barycentric interpolation on the input surface"
    return f"vertex:{TIME_FILE_ATTRIBUTE}", info


def design_layout(V, UV, F, params: UnitCell = UNIT_CELL, central_length=None) -> Layout:
    """Layout of a ready stencil (thin wrapper of :func:`pysolver.design.layout.build_layout`)."""
    return build_layout(V, UV, F, params, central_length=central_length)


def unit_cell_options(*, min_bumper=None, min_gap=None, max_cell_length=None,
                      base: UnitCell = UNIT_CELL) -> UnitCell:
    """The unit cell of a design with the tolerances a researcher varies, checked.

    Parameters
    ----------
    min_bumper : float, mm, optional
        Minimal bumper length beyond the base rim (3D scaling rule; ``--min-bumper``).
    min_gap : float, mm, optional
        Minimal flat gap between facing bumper tips (2D scaling rule; ``--min-gap``).
    max_cell_length : float, mm, optional
        Longest printable flat central length (``--max-cell-length``).
    base : UnitCell
        The values of the options not given (default: the paper's, :data:`UNIT_CELL`).

    Returns
    -------
    UnitCell
        ``dataclasses.replace(base, ...)``; equal to ``base`` when no option is given.

    Raises
    ------
    InputError
        An option outside its range in :class:`pysolver.params.Limits` (exit code 2).
    """
    given = {k: v for k, v in (("min_bumper", min_bumper), ("min_gap", min_gap),
                               ("max_cell_length", max_cell_length)) if v is not None}
    params = dataclasses.replace(base, **{k: float(v) for k, v in given.items()
                                          if _is_number(v)})
    for k, v in given.items():
        if not _is_number(v):
            raise InputError(f"--{k.replace('_', '-')} {v!r} is not a number of mm",
                             fix=f"give e.g. --{k.replace('_', '-')} {getattr(base, k):g}")
    check_unit_cell(params)
    return params


def _is_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def check_design_options(*, vertices=None, time=None, scale=1.0, flattening="cetm",
                         thickness=0.5, params: UnitCell = UNIT_CELL, size=None,
                         time_file=None) -> None:
    """Check the design options (see :func:`run_design`) without running anything.

    Raises
    ------
    InputError
        Naming the option, its value and the rule.
    """
    if not isinstance(params, UnitCell):
        raise InputError(f"params={params!r} is not a UnitCell",
                         fix="build it with pysolver.design.unit_cell_options(...)")
    check_unit_cell(params)
    if flattening not in FLATTENINGS:
        raise InputError(f"flattening={flattening!r}", fix=f"use one of {FLATTENINGS}")
    if not (np.isfinite(scale) and 0 < scale <= LIMITS.max_scale):
        raise InputError(f"--scale {scale!r} must be a positive number up to "
                         f"{LIMITS.max_scale:g}",
                         fix="e.g. --scale 1000 for a mesh in metres, 25.4 in inches")
    if size is not None:
        lo, hi = LIMITS.size_mm
        if not (_is_number(size) and np.isfinite(size) and lo <= size <= hi):
            raise InputError(f"--size {size!r} must be a length in mm from {lo:g} to {hi:g} "
                             "(the largest bounding-box extent of the target)",
                             fix="e.g. --size 106 for a shell 106 mm across")
        if scale != 1.0:
            raise InputError(f"--size {size:g} and --scale {scale:g} both set the input's "
                             "size", fix="give one of them: --size MM for a unitless mesh, "
                                         "--scale K for a mesh in other units")
    if not (params.thickness_min <= thickness <= params.thickness_max):
        raise InputError(f"thickness={thickness} mm outside {params.thickness_min}-"
                         f"{params.thickness_max} mm")
    if vertices is not None and (int(vertices) != vertices or not
                                 4 <= vertices <= LIMITS.max_vertices):
        raise InputError(f"--vertices {vertices!r} must be a whole number from 4 to "
                         f"{LIMITS.max_vertices} (about {2 * LIMITS.max_vertices} bases, "
                         "beyond any print tray)",
                         fix="omit --vertices to let the design search it")
    check_time_option(time)
    if time_file is not None:
        if time is not None:
            raise InputError(f"--time {time!r} and --time-file {time_file} both give the time "
                             "landscape", fix="give one of them")
        read_time_file(time_file)  # format and values now; the count once the mesh is read


def printable_alternatives(V, F, remesh_info: dict, params: UnitCell) -> str:
    """What would make an unprintable remeshed stencil printable, measured, for the error's fix.

    Tries the same stencil at the reference's 0.1 mm minimal bumper and names the searched
    vertex count with the shortest longest cell.

    Parameters
    ----------
    V : (n, 3) float, mm
    F : (m, 3) int
    remesh_info : dict
        :func:`pysolver.design.remesh.remesh_surface`'s info (``candidates``).
    params : UnitCell

    Returns
    -------
    fix : str
    """
    lines = []
    low = REFERENCE_MIN_BUMPER_MM
    if params.min_bumper > low + TOL.rel:
        alt = stencil_figures(V, F, replace(params, min_bumper=low))
        if alt["max_cell_length_mm"] is not None:
            ok = alt["max_cell_length_mm"] <= params.max_cell_length
            lines.append(f"--min-bumper {low:g} (the reference's) gives a longest cell of "
                         f"{alt['max_cell_length_mm']:.2f} mm on this stencil"
                         + (" (printable)" if ok else ""))
    cands = [c for c in remesh_info.get("candidates") or [] if c[4] is not None]
    if cands:
        best = min(cands, key=lambda c: c[4])
        lines.append(f"of the stencils tried, --vertices {best[0]} --seed {best[1]} came "
                     f"closest ({best[4]:.2f} mm, scale {best[3]:.2f})")
    lines.append("a cut through the region named above splits the stretch the flattening "
                 "needs (SI Note 1)")
    return "; ".join(lines)


def run_design(source, out_dir, *, vertices=None, time=None, scale=1.0, flattening="cetm",
               params: UnitCell = UNIT_CELL, thickness=0.5, central_length=None,
               stencil_order=False, progress=True, plots=True, seed=None,
               size=None, time_file=None, stencil=False, thickness_file=None) -> dict:
    """Design a shell and write the design folder.

    Parameters
    ----------
    source : str, Path or Surface
        Built-in shape (``"petal"``, ``"weave:large"``, ...), a mesh file (OBJ, STL,
        PLY, OFF; one connected disk-like surface in mm) or a stencil OBJ (v = target,
        vt = flat, row-aligned; its vertex and face order is kept).
    out_dir : str or Path
        Design folder (created if needed); files are written atomically one by one.
    vertices : int, optional
        Stencil vertex count N (default: searched to minimise the stencil scaling).
    time : None, float, str or array
        Time landscape, see :func:`pysolver.design.time_landscape.resolve_time`.  Expressions
        use the final target coordinates (``stencil.obj`` v, mm, centred).
    scale : float
        Factor applied to the input coordinates (e.g. 10 for a mesh in cm).
    size : float, mm, optional
        Scale the input instead so that its largest bounding-box extent is ``size`` mm
        (unitless meshes; exclusive with ``scale``).  The size checks and every message
        see the scaled coordinates.
    time_file : str or Path, optional
        CSV of one time (s) per vertex of the input mesh, in file order (exclusive with
        ``time``; :func:`pysolver.design.time_landscape.read_time_file`).  Carried onto the stencil
        by barycentric interpolation on the input surface, the path of a PLY vertex
        property; for a finished stencil (OBJ with vt, or ``stencil_order``) used as given.
    flattening : {"cetm", "lscm"}
        Conformal flattening used for the layout (both are computed and compared).
    params : UnitCell
    thickness : float, mm
        Uniform bracket thickness written until the temporal stage sets it.
    central_length : float, mm, optional
        Flat central length override (shortest cell); default from the shape.
    stencil_order : bool
        For an input mesh without vt: use its own triangulation as the stencil
        (no remeshing), keeping vertex and face order.
    progress : bool
        One line per stage on stderr.
    plots : bool
        Write the PNG pictures (skip in fast tests).
    seed : int, optional
        CVT remeshing seed (default: searched).
    stencil : bool
        ``source`` must be a stencil OBJ (``--stencil``; refused otherwise): its vertex
        and face order, target (v) and flat layout (vt) are used as given.
    thickness_file : str or Path, optional
        The bracket thicknesses the stencil was printed with (``--thickness-file``,
        :mod:`pysolver.design.thickness_file`): written to ``cells.csv`` instead of the
        uniform ``thickness``, so the folder can be simulated without programming.

    Returns
    -------
    summary : dict
        Counts, sizes, cell lengths, distortion, scale factors, flattening comparison,
        checks and timings per stage (also in ``design.json``).
    """
    check_design_options(vertices=vertices, time=time, scale=scale, flattening=flattening,
                         thickness=thickness, params=params, size=size, time_file=time_file)
    given_th = None if thickness_file is None else read_thickness_file(thickness_file)
    out_dir = Path(out_dir)
    clock = _Clock(progress, str(source) if not hasattr(source, "name") else source.name)
    surf, kind, src_desc, src_hash, mesh, input_scale = _load_source(source, scale, size,
                                                                     stencil)
    time_opt, time_file_info = time, None
    if time_file is not None:
        time, time_file_info = _time_file_source(time_file, mesh, surf, stencil_order)
    check_time_source(time, mesh)
    sequence = None
    if time is None and surf.time is None and mesh is not None:
        time, sequence = sequencing_landscape(mesh.V, mesh.F)
    clock.step("load")


    remesh_info = {}
    comparison = {}
    if vertices is not None and (surf.UV is not None or stencil_order):
        what = ("a finished stencil (its own flat layout)" if kind != "builtin"
                else "a fixed tessellation")
        raise InputError(f"--vertices {vertices} has no effect on {src_desc}: it is {what}, "
                         "not remeshed.",
                         fix="omit --vertices for this input; it applies to surfaces that are "
                             "remeshed (built-in curved shapes and mesh files).")
    if surf.UV is not None:
        V0, UV0, F0 = surf.V, surf.UV, surf.F
        remesh_info = {"remeshed": False, "vertices": int(len(V0))}
        clock.step("remesh")
        clock.step("flatten")
    else:
        if stencil_order:
            V0, F0 = surf.V, surf.F
            remesh_info = {"remeshed": False, "vertices": int(len(V0))}
        else:

            V0, F0, remesh_info = remesh_surface(
                surf.V, surf.F, vertices=vertices, seed=seed, target_bases=surf.target_bases,
                params=params, time=_target_times(time, surf, mesh),
                user_times=time_opt is not None or time_file is not None,
                progress=(lambda line: print(f"[design {surf.name}] remesh {line}",
                                             file=sys.stderr, flush=True)) if progress else None)
        clock.step("remesh")
        results = compare_flattenings(V0, F0, params=params)
        comparison = {k: r.metrics for k, r in results.items()}
        chosen = results[flattening]
        if chosen.UV is None:
            raise InputError(f"flattening {flattening!r} failed: {chosen.metrics['error']}",
                             fix="try the other flattening or remesh the surface")
        UV0 = chosen.UV
        clock.step("flatten")

    cl = central_length if central_length is not None else surf.central_length
    lay = build_layout(V0, UV0, F0, params, central_length=cl)
    clock.step("layout")

    nodes_t, _ = bracket_nodes(lay.V, lay.UV, lay.F, params, ff=lay.ff,
                               rotvec=lay.rotvec)
    coll = collision_lengths(nodes_t, lay.cells)
    clock.step("nodes")

    # time landscape: built-in defaults see the shape's own frame; user input the target
    center = np.asarray(V0, float).mean(axis=0)
    if time is None and surf.time is not None:
        t_vertex, t_desc = resolve_time(None, lay.V,
                                        default=lambda X: surf.time(X / lay.scale3d + center))
    else:
        src_mesh = None
        if mesh is not None:
            src_mesh = mesh.transformed(-center, lay.scale3d)
        t_vertex, t_desc = resolve_time(time, lay.V, source_mesh=src_mesh)
        if time_file_info is not None:
            t_desc = f"--time-file {time_file_info['path']}, {time_file_info['carried']}"
        elif time is not None and sequence is not None:
            t_desc = sequence["description"]
    t_star = cell_target_times(t_vertex, lay.cells.verts[:, 0], lay.cells.verts[:, 1])
    th = np.full((len(lay.cells.faces), 2), float(thickness))
    if given_th is not None:
        th = cell_thicknesses(given_th, lay.cells.faces, params)
    clock.step("time")

    # messages name places on the target in mm (the scaled, centred stencil.obj v): the
    # input may be unitless (--size) or in other units (--scale)
    report = check_layout(lay, params, raise_=False)

    dist = distortion_metrics(lay.V, lay.UV, lay.F, params=params, layout=lay)
    clock.step("checks")
    if remesh_info.get("remeshed") and remesh_info.get("rim_inset_mm"):

        cover = surface_area(V0, F0) / remesh_info["area_mm2"]
        remesh_info["area_covered"] = round(cover, 4)
        report.warnings.append(
            f"the stencil stops {remesh_info['rim_inset_mm'] * lay.scale3d:.1f} mm inside the "
            f"target's rim and covers {100 * cover:.0f} % of its area (a CVT's outer sites lie "
            "inside its domain; the reference's stencils cover 80-88 %)"
            + (f"; {remesh_info['rim']['why']}"
               if (remesh_info.get("rim") or {}).get("fallback") else ""))
    if (remesh_info.get("remeshed")
            and lay.central_length.max() > params.max_cell_length):
        report.errors.append(("", printable_alternatives(V0, F0, remesh_info, params)))
    report.raise_if_failed()

    out_dir.mkdir(parents=True, exist_ok=True)
    write_design_tables(out_dir, lay, coll, t_vertex, t_star, th, params)
    clock.step("write")

    summary = _summary(surf, kind, src_desc, lay, report, dist, comparison, remesh_info,
                       flattening if surf.UV is None else "given", t_desc, t_vertex, coll)
    if plots:

        pics = write_design_plots(lay, out_dir, t_vertex, th)
        clock.step("plots")
        summary["pictures"] = [p.name for p in pics]
    summary["timings_s"] = dict(clock.t)
    options = {
        "source": src_desc, "source_kind": kind, "source_sha256_16": src_hash,
        "vertices": vertices, "seed": seed,
        "time": (time_opt if isinstance(time_opt, (str, int, float, type(None)))
                 else "array"),
        "time_file": time_file_info,
        "sequencing": sequence,
        "scale": scale, "size_mm": size, "input_scale": input_scale,
        "flattening": flattening, "thickness_mm": thickness,
        "central_length_mm": cl, "stencil_order": stencil_order, "stencil": stencil,
        "thickness_file": None if given_th is None else {
            "path": given_th["path"], "sha256": given_th["sha256"],
            "rows": int(len(given_th["bases"]))},
        "params": params.to_dict(),
        "scale3d": lay.scale3d, "scale2d": lay.scale2d, "scale2d_rule": lay.scale2d_rule,
        "alignment_bases": [int(i) for i in lay.alignment],
    }
    _write_json(out_dir / "design.json", {"options": options, "summary": summary})
    return summary


def write_design_tables(out_dir, lay: Layout, coll, t_vertex, t_star, thickness,
                        params: UnitCell = UNIT_CELL) -> None:
    """Write stencil.obj, the five CSV tables and ``model.npz`` of a layout into ``out_dir``."""
    out_dir = Path(out_dir)
    F = lay.F
    m = len(F)
    align = np.zeros(m, dtype=bool)
    align[lay.alignment] = True
    tables.write_stencil(out_dir / "stencil.obj", lay.V, lay.UV, F)
    tables.write_table(out_dir / "bases.csv", "bases", {
        "base_id": np.arange(m), "v0": F[:, 0], "v1": F[:, 1], "v2": F[:, 2],
        "flat_x_mm": lay.C2[:, 0], "flat_y_mm": lay.C2[:, 1],
        "target_x_mm": lay.Fc[:, 0], "target_y_mm": lay.Fc[:, 1], "target_z_mm": lay.Fc[:, 2],
        "normal_x": lay.N[:, 0], "normal_y": lay.N[:, 1], "normal_z": lay.N[:, 2],
        "rot_x_rad": lay.rotvec[:, 0], "rot_y_rad": lay.rotvec[:, 1],
        "rot_z_rad": lay.rotvec[:, 2], "ref_slot": lay.ref_slot,
        "boundary": lay.boundary_face, "alignment": align})
    c = lay.cells
    nc = len(c.faces)
    tables.write_table(out_dir / "cells.csv", "cells", {
        "cell_id": np.arange(nc), "base_a": c.faces[:, 0], "base_b": c.faces[:, 1],
        "slot_a": c.slots[:, 0], "slot_b": c.slots[:, 1],
        "vertex_a": c.verts[:, 0], "vertex_b": c.verts[:, 1], "boundary": c.boundary,
        "central_length_mm": lay.central_length,
        "bracket_length_mm": params.bracket_length(lay.central_length),
        "target_length_mm": lay.target_length, "fold_angle_deg": lay.fold_angle_deg,
        "collision_length_top_mm": coll[:, 0], "collision_length_bottom_mm": coll[:, 1],
        "t_star_s": t_star, "thickness_top_mm": thickness[:, 0],
        "thickness_bottom_mm": thickness[:, 1],
        "t_min_s": np.full(nc, np.nan), "t_max_s": np.full(nc, np.nan),
        "clamped": np.zeros(nc, dtype=bool)})
    b = lay.bumpers
    tables.write_table(out_dir / "bumpers.csv", "bumpers", {
        "base_id": b.base, "layer": np.where(b.layer == 0, "top", "bottom"), "slot": b.slot,
        "cell_id": b.cell, "neighbour": b.neighbour, "dir_deg": b.dir_deg,
        "plane_px": b.plane_p[:, 0], "plane_py": b.plane_p[:, 1], "plane_pz": b.plane_p[:, 2],
        "plane_nx": b.plane_n[:, 0], "plane_ny": b.plane_n[:, 1], "plane_nz": b.plane_n[:, 2],
        "cut": b.cut, "length_mm": b.length})
    tables.write_table(out_dir / "time_landscape.csv", "time_landscape", {
        "vertex_id": np.arange(len(lay.V)), "time_s": t_vertex})
    tables.write_table(out_dir / "support_frame.csv", "support_frame", {
        "x_mm": lay.support[:, 0], "y_mm": lay.support[:, 1]})
    write_model_file(out_dir, params)


def _r(x, k=4):
    return round(float(x), k)


def _summary(surf, kind, src_desc, lay: Layout, report, dist, comparison, remesh_info,
             flattening, t_desc, t_vertex, coll) -> dict:
    l = lay.central_length
    ratio = lay.target_length / l
    flat_ext = np.ptp(lay.C2, axis=0) + 2 * UNIT_CELL.base_r
    tgt_ext = np.ptp(lay.V, axis=0)
    return {
        "shape": surf.name, "source": src_desc, "source_kind": kind,
        "counts": {"vertices": int(len(lay.V)), "bases": int(len(lay.F)),
                   "cells": int(len(lay.cells.faces)),
                   "boundary_cells": int(lay.cells.boundary.sum()),
                   "boundary_bases": int(lay.boundary_face.sum()),
                   "alignment_bases": int(len(lay.alignment)),
                   "bumpers": int(len(lay.bumpers))},
        "size_mm": {"flat_xy": [_r(flat_ext[0], 2), _r(flat_ext[1], 2)],
                    "target_xyz": [_r(v, 2) for v in tgt_ext]},
        "cell_length_mm": {"min": _r(l.min()), "max": _r(l.max()), "mean": _r(l.mean())},
        "contraction_target_over_flat": {"min": _r(ratio.min()), "max": _r(ratio.max())},
        "collision_length_mm": {"min": _r(coll.min()), "max": _r(coll.max())},
        "fold_angle_deg_absmax": _r(np.abs(lay.fold_angle_deg).max(), 2),
        "bumper_cuts": {"bisector": int(np.sum(lay.bumpers.cut == "bisector")),
                        "straight": int(np.sum(lay.bumpers.cut == "straight"))},
        "scale": {"scale3d": _r(lay.scale3d, 6), "scale2d": _r(lay.scale2d, 6),
                  "scale2d_rule": _r(lay.scale2d_rule, 6)},
        "distortion": dist,
        "flattening": {"method": flattening, "comparison": comparison},
        "remesh": remesh_info,
        "time": {"source": t_desc, "min_s": _r(t_vertex.min(), 3), "max_s": _r(t_vertex.max(), 3)},
        "checks": report.to_dict(),
    }


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(type(o))


def _write_json(path: Path, data: dict):
    tmp = path.with_suffix(".json.tmp")
    with open(tmp, "w", newline="\n") as fh:
        json.dump(data, fh, indent=1, sort_keys=False, default=_json_default)
        fh.write("\n")
    os.replace(tmp, path)


__all__ = ["run_design", "check_design_options", "unit_cell_options",
           "design_layout", "write_design_tables", "FLATTENINGS"]
