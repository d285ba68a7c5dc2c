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
import sys
from pathlib import Path

import numpy as np

from .. import tables
from ..core.progress import Clock
from ..core.records import json_text
from ..core.staging import output_folder
from ..core.writes import atomic_write_text
from ..errors import InputError
from ..geometry import signed_areas_2d
from ..params import LIMITS, UNIT_CELL, UnitCell, check_unit_cell
from . import surfaces
from .cellnodes import bracket_nodes, collision_lengths, write_model_file
from .checks import check_layout
from .flatten import compare_flattenings, distortion_metrics
from .layout import Layout, build_layout
from .mesh_input import load_input, size_factor
from .plots import write_design_plots
from .stencil import printable_alternatives, remesh_surface, size_refusal, surface_area
from .thickness_file import cell_thicknesses, read_thickness_file
from .time_landscape import (
    DesignLandscape,
    cell_target_times,
    check_time_option,
    read_time_file,
    write_landscape,
)

FLATTENINGS = ("cetm", "lscm")


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


def _check_given_layout(UV, F, src: str, asked: bool) -> None:
    """Refuse a stencil whose flat layout (its ``vt``) is not one: triangles of both
    orientations, or degenerate.  The fix names the way to design the mesh as a target."""
    A = signed_areas_2d(UV, F)
    bad = int(min(np.sum(A > 0), np.sum(A < 0)) + np.sum(A == 0))
    if bad:
        why = "--stencil was given" if asked else "it carries morphshell's stencil marker"
        raise InputError(
            f"{src} is read as a finished stencil ({why}), but its flat layout (vt) is not a "
            f"valid one: {bad} of its {len(F)} flat triangles are inverted or degenerate "
            "(a texture's UV map is not a stencil)",
            fix="to design this mesh as a target surface, give it without --stencil (its vt "
                "is then ignored)" if asked else
                "remove the first line (the marker) to design the mesh as a target surface")


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


def run_design(source, out_dir, *, vertices=None, time=None, scale=1.0, flattening="cetm",
               params: UnitCell = UNIT_CELL, thickness=0.5, central_length=None,
               stencil=False, progress=True, plots=True, seed=None,
               size=None, time_file=None, thickness_file=None) -> dict:
    """Design a shell and write the design folder.

    Parameters
    ----------
    source : str, Path or Surface
        Built-in shape (``"petal"``, ``"weave:large"``, ...), a mesh file (OBJ, STL,
        PLY, OFF; one connected disk-like surface in mm) or a stencil OBJ (v = target,
        vt = flat, row-aligned; its vertex and face order is kept).
    out_dir : str or Path
        Design folder: new, empty, or one morphshell made (``claim_output``); it appears
        complete or not at all (:func:`pysolver.core.staging.output_folder`).
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
        CSV of one time (s) per input-mesh vertex, in file order (exclusive with ``time``;
        :func:`~pysolver.design.time_landscape.read_time_file`); carried onto the stencil as a
        PLY vertex property is, or used as given for a finished stencil.
    flattening : {"cetm", "lscm"}
        Conformal flattening used for the layout (both are computed and compared).
    params : UnitCell
    thickness : float, mm
        Uniform bracket thickness written until the temporal stage sets it.
    central_length : float, mm, optional
        Flat central length override (shortest cell); default from the shape.
    stencil : bool
        The input mesh is a finished stencil (``--stencil``): its own triangulation is the
        stencil (no remeshing; vertex and face order kept), its ``vt`` (an OBJ) the flat
        layout, else it is flattened.  Without it a mesh with a UV map is a target surface;
        only an OBJ with morphshell's stencil marker is read as a stencil.
    progress : bool
        One line per stage on stderr.
    plots : bool
        Write the PNG pictures (skip in fast tests).
    seed : int, optional
        CVT remeshing seed (default: searched).
    thickness_file : str or Path, optional
        The thicknesses the stencil was printed with, instead (``--thickness-file``).

    Returns
    -------
    summary : dict
        Counts, sizes, cell lengths, distortion, scale factors, flattening comparison,
        checks and timings per stage (also in ``design.json``).

    Examples
    --------
    A four-vertex patch of eight bases (``tmp`` is a scratch folder; the examples of the
    later stages continue on this ``folder``):

    >>> from pysolver.design import run_design
    >>> folder = tmp / "patch"
    >>> s = run_design("regular:rows=2,cols=2", folder, progress=False, plots=False)
    >>> s["counts"]["bases"], s["counts"]["cells"]
    (8, 8)
    """
    check_design_options(vertices=vertices, time=time, scale=scale, flattening=flattening,
                         thickness=thickness, params=params, size=size, time_file=time_file)
    clock = Clock(progress, str(source) if not hasattr(source, "name") else source.name)
    inp = _read_input(source, scale, size, stencil, time, time_file, vertices, thickness_file)
    surf = inp.surf
    clock.step("load")
    st = _stencil(surf, inp.desc, inp.land, clock, vertices=vertices, seed=seed, params=params,
                  flattening=flattening, stencil=stencil, progress=progress)
    cl = central_length if central_length is not None else surf.central_length
    lay, coll = _layout(st, params, cl, clock)
    t_vertex, t_desc, t_star = _landscape_on_stencil(inp.land, st, lay)
    th = _thicknesses(inp.thickness, lay, thickness, params)
    clock.step("time")
    report, dist = _check(surf, st, lay, params, vertices)
    clock.step("checks")
    options = _options(inp, lay, vertices=vertices, seed=seed, time=time, scale=scale,
                       size=size, flattening=flattening, thickness=thickness,
                       central_length=cl, stencil=stencil, params=params)
    summary = _summary(surf, inp.kind, inp.desc, lay, report, dist, st.comparison, st.remesh,
                       flattening if surf.UV is None else "given", t_desc, t_vertex, coll)
    write_design_folder(out_dir, lay, coll, t_vertex, t_star, th, params,
                  {"options": options, "summary": summary}, plots, clock)
    return summary


def write_design_folder(out_dir, lay: Layout, coll, t_vertex, t_star, thickness,
                        params: UnitCell, record: dict, plots: bool = True, clock=None) -> None:
    """Write the design folder: the tables (:func:`write_design_tables`), the pictures and
    ``design.json`` (``record``: ``options`` and ``summary``, the summary completed with the
    pictures and the timings).  The folder appears whole, or not at all (in place in a
    build's private staging).

    Parameters
    ----------
    out_dir : path-like
    lay, coll, t_vertex, t_star, thickness, params
        As :func:`write_design_tables`.
    record : dict
        ``{"options": ..., "summary": ...}``.
    plots : bool
        Draw the PNG pictures.
    clock : optional
        The design's stage clock (its ``step(name)`` is called after each step).
    """
    summary = record["summary"]
    step = clock.step if clock is not None else (lambda name: None)
    with output_folder(Path(out_dir)) as out_dir:
        write_design_tables(out_dir, lay, coll, t_vertex, t_star, thickness, params)
        step("write")
        if plots:
            summary["pictures"] = [p.name for p in
                                   write_design_plots(lay, out_dir, t_vertex, thickness)]
            step("plots")
        if clock is not None:
            summary["timings_s"] = dict(clock.t)
        _write_json(out_dir / "design.json", record)


def _thicknesses(given, lay: Layout, thickness: float, params: UnitCell) -> np.ndarray:
    """The bracket thickness of every cell and layer (c, 2) mm: the uniform ``thickness``, or
    the rows of a thickness file (:func:`~pysolver.design.thickness_file.cell_thicknesses`)."""
    if given is None:
        return np.full((len(lay.cells.faces), 2), float(thickness))
    return cell_thicknesses(given, lay.cells.faces, params)


def _landscape_on_stencil(land: DesignLandscape, st, lay: Layout):
    """The landscape at the stencil's vertices (its frame: centred on the stencil, scaled by
    its 3D scaling, ``stencil.obj`` v) and ``t*`` per cell.

    Returns
    -------
    t_vertex : (n_vertices,) float, s
    description : str
    t_star : (n_cells,) float, s
    """
    t_vertex, desc = land.at(lay.V, np.asarray(st.V, float).mean(axis=0), lay.scale3d)
    t_star = cell_target_times(t_vertex, lay.cells.verts[:, 0], lay.cells.verts[:, 1])
    return t_vertex, desc, t_star


def _options(inp, lay: Layout, *, vertices, seed, time, scale, size, flattening, thickness,
             central_length, stencil, params: UnitCell) -> dict:
    """``design.json`` → ``options``: what the design was made with (docs/design-folder.md)."""
    return {
        "source": inp.desc, "source_kind": inp.kind, "source_sha256_16": inp.sha,
        "vertices": vertices, "seed": seed,
        "time": (time if isinstance(time, (str, int, float, type(None))) else "array"),
        "time_file": inp.land.time_file, "sequencing": inp.land.sequencing,
        "scale": scale, "size_mm": size, "input_scale": inp.scale,
        "flattening": flattening, "thickness_mm": thickness,
        "central_length_mm": central_length, "stencil": stencil, "params": params.to_dict(),
        "scale3d": lay.scale3d, "scale2d": lay.scale2d, "scale2d_rule": lay.scale2d_rule,
        "alignment_bases": [int(i) for i in lay.alignment],
        "thickness_file": None if inp.thickness is None else {
            "path": inp.thickness["path"], "sha256": inp.thickness["sha256"],
            "rows": int(len(inp.thickness["bases"]))},
    }


def _layout(st, params: UnitCell, central_length, clock: Clock):
    """The flat layout of a stencil (scaling rules, bases, bumpers) and its cells' collision
    lengths (from the bracket nodes).

    Returns
    -------
    lay : Layout
    coll : (n_cells, 2) float, mm -- ``collision_length_top_mm``, ``_bottom_mm``
    """
    lay = build_layout(st.V, st.UV, st.F, params, central_length=central_length)
    clock.step("layout")
    nodes_t, _ = bracket_nodes(lay.V, lay.UV, lay.F, params, ff=lay.ff, rotvec=lay.rotvec)
    coll = collision_lengths(nodes_t, lay.cells)
    clock.step("nodes")
    return lay, coll


@dataclasses.dataclass
class _Input:
    """The design's input, read: the target ``surf`` (a :class:`~pysolver.design.surfaces.
    Surface`), its ``kind`` ("builtin", "mesh", "stencil"), description ``desc`` and hash
    ``sha``, the input ``mesh`` (None for a built-in shape), the factor ``scale`` applied to
    its coordinates, its time landscape ``land``, resolved once, and the bracket thicknesses
    of a ``--thickness-file`` (:func:`~pysolver.design.thickness_file.read_thickness_file`)
    or None."""

    surf: surfaces.Surface
    kind: str
    desc: str
    sha: str
    mesh: object
    scale: float
    land: DesignLandscape
    thickness: dict | None = None


def _read_input(source, scale, size, stencil: bool, time, time_file, vertices,
                thickness_file=None) -> _Input:
    """Load the source and resolve its time landscape; read the thickness file; refuse
    ``--vertices`` for an input that is not remeshed."""
    given_th = None if thickness_file is None else read_thickness_file(thickness_file)
    surf, kind, desc, sha, mesh, input_scale = _load_source(source, scale, size, stencil)
    land = DesignLandscape.from_options(time, time_file, default=surf.time, mesh=mesh,
                                        name=surf.name,
                                        stencil_input=surf.UV is not None or stencil)
    if vertices is not None and (surf.UV is not None or stencil):
        what = ("a finished stencil (its own flat layout)" if kind != "builtin"
                else "a fixed tessellation")
        raise InputError(f"--vertices {vertices} has no effect on {desc}: it is {what}, "
                         "not remeshed.",
                         fix="omit --vertices for this input; it applies to surfaces that are "
                             "remeshed (built-in curved shapes and mesh files).")
    return _Input(surf, kind, desc, sha, mesh, input_scale, land, given_th)


@dataclasses.dataclass
class _Stencil:
    """The stencil of a design before its layout: target ``V`` (n, 3) mm, flat ``UV``
    (n, 2) mm, faces ``F`` (m, 3); how it was made (``remesh``, the flattenings'
    ``comparison``) and ``rerun(factor, params) -> remesh record``, which searches the target
    again (the refusals' measured alternatives), or None; ``rim_u`` (n,) the CETM's boundary
    log-scale when the search freed the rim's scale (``remesh["rim_scale"]``), else None."""

    V: np.ndarray
    UV: np.ndarray
    F: np.ndarray
    remesh: dict
    comparison: dict
    rerun: object = None
    rim_u: np.ndarray | None = None


def _stencil(surf, src_desc: str, land: DesignLandscape, clock: Clock, *, vertices, seed,
             params: UnitCell, flattening: str, stencil: bool, progress: bool) -> _Stencil:
    """The stencil: a finished one as given (checked), else the target remeshed (the count
    search, with the landscape on the target) and flattened."""
    if surf.UV is not None:
        _check_given_layout(surf.UV, surf.F, src_desc, stencil)
        clock.step("remesh")
        clock.step("flatten")
        return _Stencil(surf.V, surf.UV, surf.F, {"remeshed": False, "vertices": int(len(surf.V))},
                        {})
    rerun = None
    if stencil:
        V0, F0 = surf.V, surf.F
        remesh_info = {"remeshed": False, "vertices": int(len(V0))}
    else:
        t_target = land.on_target(surf.V)

        def search(factor=1.0, p=params, say=None):
            return remesh_surface(
                surf.V * factor, surf.F, vertices=vertices, seed=seed,
                target_bases=surf.target_bases, params=p, time=t_target,
                user_times=land.given, progress=say)
        V0, F0, remesh_info = search(say=(lambda line: print(
            f"[design {surf.name}] remesh {line}", file=sys.stderr, flush=True))
            if progress else None)
        rerun = lambda f, p: search(f, p)[2]  # the refusals' measured alternatives
    clock.step("remesh")
    rim_u = remesh_info.pop("rim_log_scale", None)  # (per vertex: not for design.json)
    results = compare_flattenings(V0, F0, params=params, u_boundary=rim_u)
    chosen = results[flattening]
    if chosen.UV is None:
        raise InputError(f"flattening {flattening!r} failed: {chosen.metrics['error']}",
                         fix="try the other flattening or remesh the surface")
    clock.step("flatten")
    return _Stencil(V0, chosen.UV, F0, remesh_info, {k: r.metrics for k, r in results.items()},
                    rerun, rim_u)


def _check(surf, st: _Stencil, lay: Layout, params: UnitCell, vertices):
    """The layout checks and the distortion; a stencil that does not print (or not at the
    size asked for) is refused, naming measured alternatives.  Messages name places on the
    target in mm (the scaled, centred ``stencil.obj`` v): the input may be unitless
    (``--size``) or in other units (``--scale``).

    Returns
    -------
    report : pysolver.design.checks.CheckReport
    dist : dict -- :func:`pysolver.design.flatten.distortion_metrics`
    """
    report = check_layout(lay, params, raise_=False)
    dist = distortion_metrics(lay.V, lay.UV, lay.F, params=params, layout=lay)
    remesh_info = st.remesh
    if remesh_info.get("remeshed") and remesh_info.get("rim_inset_mm"):
        cover = surface_area(st.V, st.F) / remesh_info["area_mm2"]
        remesh_info["area_covered"] = round(cover, 4)
        report.warnings.append(
            f"the stencil stops {remesh_info['rim_inset_mm'] * lay.scale3d:.1f} mm inside the "
            f"target's rim and covers {100 * cover:.0f} % of its area (a CVT's outer sites lie "
            "inside its domain; the reference's stencils cover 80-88 %)"
            + (f"; {remesh_info['rim']['why']}"
               if (remesh_info.get("rim") or {}).get("fallback") else ""))
    report.warnings.extend(remesh_info.get("warnings") or [])
    extent = float(np.ptp(surf.V, axis=0).max())
    if (remesh_info.get("remeshed")
            and lay.central_length.max() > params.max_cell_length):
        report.errors.append(("", printable_alternatives(st.V, st.F, remesh_info, params,
                                                         st.rerun, extent, (surf.V, surf.F),
                                                         u_boundary=st.rim_u)))
    elif remesh_info.get("remeshed") and vertices is None \
            and not remesh_info.get("at_size", True):
        raise size_refusal(remesh_info, params, st.rerun, extent)
    report.raise_if_failed()
    return report, dist


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
    write_landscape(out_dir, t_vertex)
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


def _write_json(path: Path, data: dict):
    atomic_write_text(path, json_text(data, indent=1, sort_keys=False))


__all__ = ["run_design", "check_design_options", "unit_cell_options",
           "design_layout", "write_design_tables", "write_design_folder", "FLATTENINGS"]
