"""The render stage: a design folder to printable STLs, OpenSCAD per part, manifold3d union
per layer.

Pipeline (``render_design``)
----------------------------
1. :mod:`pysolver.render.scad_io` writes one ``.scad`` data file per part into
   ``<design>/scad/`` (part = one base of one layer, plus its actuated-pose twin,
   the two support frames and one marker dot).  Each file ``use``s the OpenSCAD
   library ``scad/`` by path.
2. Every part whose STL is not cached is rendered by the chosen renderer
   (``renderer``, :data:`RENDERERS`): ``openscad`` runs one OpenSCAD process per part
   (``openscad --export-format binstl -o part.stl part.scad``) in a pool of ``jobs``
   workers (default: CPU count) -- OpenSCAD's implicit CGAL union grows faster than
   linearly with the part size, so one small file per part is much faster than one
   file per layer (``shared/design/dependencies.md``); ``fast`` evaluates the same
   files with openscad-evaluator in ``jobs`` worker processes
   (:mod:`pysolver.render.fast`, ~20x faster per part), and a part it fails on is
   rendered by OpenSCAD instead; ``auto`` is ``fast`` once :func:`fast_self_check`
   has found it to agree with OpenSCAD on reference parts of the library, else
   ``openscad``.
3. Part STLs are cached in ``cache_dir`` under a hash of the part file's text,
   the text of every ``.scad`` file of the library and the renderer's name and
   version: an edit of any library file (e.g. a module default) re-renders every
   part with no Python change; an unchanged re-render reads everything from the cache.
4. The parts of a layer are moved to the print frame
   (:func:`pysolver.geometry.print_transform`: bed at z = 0, brackets down, top
   layer turned over about x) and united with manifold3d into one watertight
   solid.  Each cell's bracket is drawn whole by one of its two bases
   (:func:`pysolver.render.scad_io.bracket_owner`) and the far ends of its V's are anchored
   inside the other base's disc, so a layer is a single connected volume and no bracket
   apex is a joint between two parts.
5. ``<design>/stl/`` receives ``top.stl``, ``bottom.stl``, ``markers_top.stl``,
   ``markers_bottom.stl``, ``support_frame_top.stl``, ``support_frame_bottom.stl``
   and ``actuated.stl`` (target frame: each node at its base's target pose, brackets
   opened to the target spans, the two layers 0.5 mm apart where the membrane is; a
   preview made of one separate solid per node),
   written into a temporary folder and moved into place at the end.

Faceting: circles are inscribed regular polygons with a sagitta of at most
``FACET_TOL = 0.005 mm`` (``scad/params.scad``): base discs are 48-gons, whose
area is 0.29 % below the circle's.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import time
from pathlib import Path

import numpy as np

from ..core.progress import say
from ..core.records import json_text
from ..core.staging import atomic_dir
from ..geometry import print_transform, rotvec_to_matrix
from ..params import LAYERS, SIM, UNIT_CELL, layer_sign
from ..params import tol as TOL
from ..tables import PARTS_RECORD, tables_sha256
from .parts import DEFAULT_RENDERER, check_renderer, default_cache_dir, find_openscad, render_parts
from .scad_io import SCAD_DIR, Part, check_library, read_design, write_part_files
from .solids import (
    affine_rows,
    as_float32,
    describe_stl,
    from_manifold,
    load_stl,
    to_manifold,
    union,
)

STL_FILES = {
    "top": "top.stl", "bottom": "bottom.stl",
    "markers_top": "markers_top.stl", "markers_bottom": "markers_bottom.stl",
    "support_frame_top": "support_frame_top.stl",
    "support_frame_bottom": "support_frame_bottom.stl",
    "actuated": "actuated.stl",
}

EXPORT_SIMPLIFY_MM = 0.0
"""Tolerance (mm) of the manifold3d ``simplify`` run on every output before writing it:
0 drops only zero-area triangles and doubled vertices.  A larger tolerance does not
help against the non-manifold edges that float32 STL rounding can make: 1e-4 mm removed
neither those of the former two-part bracket apexes (faces of two parts passing within
~1e-5 mm of each other without sharing an edge) nor the rare ones where a V end of one
part crosses the neighbour's disc rim ~2e-6 mm from a polygon vertex (simplify keeps both
corners); 1e-5 mm neither.  Those are welded as the STL stores them (:func:`as_float32`)."""


def render_design(design_dir, *, jobs=None, cache_dir=None, scad_dir=None, progress=True,
                  actuated: bool = True, renderer=None) -> dict:
    """Render the printable STLs of a design folder.

    Parameters
    ----------
    design_dir : path-like
        Design folder (tables; see ``docs/design-folder.md``).
    jobs : int, optional
        Parallel OpenSCAD processes (default: CPU count).
    cache_dir : path-like, optional
        Part STL cache (default ``build/.cache/parts`` of the enclosing ``build``
        folder, else ``<design_dir>/../.cache/parts``).
    scad_dir : path-like, optional
        OpenSCAD library (default: the repository's ``scad/``).  An edited copy
        changes every part's cache key.
    progress : bool
        Progress bar and one line per step on stderr.
    actuated : bool
        Also render ``actuated.stl`` (the shell in its target pose).
    renderer : {"openscad", "fast", "auto"}, optional
        Part renderer (default :data:`DEFAULT_RENDERER`), see :func:`render_parts`.

    Returns
    -------
    summary : dict
        ``parts``, ``rendered``, ``cached``, ``seconds_per_part`` (mean renderer
        wall time of the parts rendered now, None if all were cached),
        ``wall_seconds_per_part`` (pool wall time / rendered parts),
        ``cpu_seconds_per_part`` (renderer CPU time / rendered parts),
        ``stl`` {key: path}, ``watertight`` {key: bool}, ``bodies``, ``volumes_mm3``,
        ``bbox_mm`` {key: [[xmin, ymin, zmin], [xmax, ymax, zmax]]}, ``timings_s``,
        ``openscad``, ``renderer`` (backend used), ``renderer_version``,
        ``fallback_parts`` (parts the fast renderer failed on, rendered by OpenSCAD),
        ``jobs``, ``cache_dir``, ``scad_dir``, ``facet_tol_mm``.

    Raises
    ------
    ExternalToolError
        The renderer missing or failing on some parts (named by base id and layer).
    InputError
        Bad or missing tables.
    """
    t_start = time.perf_counter()
    design_dir = Path(design_dir).resolve()
    scad_dir = check_library(Path(scad_dir).resolve() if scad_dir else SCAD_DIR)
    cache_dir = Path(cache_dir) if cache_dir else default_cache_dir(design_dir)
    renderer = check_renderer(DEFAULT_RENDERER if renderer is None else renderer)
    exe = None if renderer == "fast" else find_openscad()   # fast: OpenSCAD only as fallback
    log = functools.partial(say, "render", design_dir.name, enabled=progress)
    made_from = tables_sha256(design_dir)   # recorded with the STLs (stl/parts.json)
    design = read_design(design_dir)
    t0 = time.perf_counter()
    with atomic_dir(design_dir / "scad") as tmp:
        parts = write_part_files(design_dir, tmp, scad_dir=scad_dir, actuated=actuated,
                                 design=design)
    parts = [dataclasses.replace(p, path=design_dir / "scad" / p.path.name) for p in parts]
    t_write = time.perf_counter() - t0
    log(f"{len(parts)} part files in scad/; cache {cache_dir}")
    res = render_parts(parts, cache_dir=cache_dir, scad_dir=scad_dir, jobs=jobs,
                       progress=progress, exe=exe, renderer=renderer)
    _log_rendered(res, log)
    t0 = time.perf_counter()
    solids = {p.name: to_manifold(load_stl(res["stl"][p.name]), f"part STL of {p.name}")
              for p in parts}
    outputs = assemble_layers(parts, solids, design, actuated=actuated)
    t_union = time.perf_counter() - t0
    t0 = time.perf_counter()
    info = _export(design_dir, outputs, made_from)
    t_export = time.perf_counter() - t0
    _warn_solids(info, log)
    summary = _render_summary(parts, res, info, design_dir)
    summary.update({"timings_s": {"write_scad": round(t_write, 3),
                                  "self_check": round(res["self_check_s"], 3),
                                  "openscad": round(res["wall_s"], 3),
                                  "union": round(t_union, 3), "export": round(t_export, 3),
                                  "total": round(time.perf_counter() - t_start, 3)},
                    "cache_dir": str(cache_dir), "scad_dir": str(scad_dir)})
    log(f"done in {summary['timings_s']['total']:.1f} s -> stl/")
    return summary


def assemble_layers(parts, solids: dict, design, *, actuated: bool = True) -> dict:
    """The printable solids from the rendered parts: per layer the union of its nodes, its
    support frame and its marker dots, in the print frame; and the shell in its target
    pose (``actuated``).

    Parameters
    ----------
    parts : list of Part
    solids : dict
        {part name: manifold3d solid} of every part.
    design : pysolver.tables.Design
    actuated : bool

    Returns
    -------
    dict
        {:data:`STL_FILES` key: manifold3d solid}.
    """
    by_kind: dict[tuple, list[Part]] = {}
    for p in parts:
        by_kind.setdefault((p.kind, p.layer), []).append(p)
    outputs = {}
    for layer in LAYERS:
        T = affine_rows(print_transform(layer))
        outputs[layer] = union([solids[p.name].transform(T) for p in by_kind[("node", layer)]])
        frame = by_kind[("frame", layer)][0]
        outputs[f"support_frame_{layer}"] = solids[frame.name].transform(T)
        # the marker dot is modelled in the layer-local frame (z up from the membrane)
        s = layer_sign(layer)
        dot = solids[by_kind[("marker", None)][0].name]
        rows = np.flatnonzero(~np.asarray(design.bases["alignment"], bool))
        dots = []
        for r in rows:
            A = np.diag([1.0, 1.0, float(s), 1.0])
            A[:2, 3] = [design.bases["flat_x_mm"][r], design.bases["flat_y_mm"][r]]
            dots.append(dot.transform(affine_rows(print_transform(layer) @ A)))
        outputs[f"markers_{layer}"] = union(dots)
    if actuated:
        outputs["actuated"] = _actuated(by_kind, solids, design)
    return outputs


def _actuated(by_kind: dict, solids: dict, design):
    """The shell in its target pose: every node at ``p_target = c + R (p + s m/2 z)``, the
    part being drawn about its base centre.  The layers are moved apart by the membrane
    thickness m (0.5 mm): that is where they sit on the real shell, and two layers touching
    face to face at the mid-plane would make the union fragile (coincident rims from
    different parts).  The opened arms stop short of each other (APEX_GAP): every node is
    its own solid."""
    row_of = {int(b): r for r, b in enumerate(design.bases["base_id"])}
    rot = np.c_[design.bases["rot_x_rad"], design.bases["rot_y_rad"],
                design.bases["rot_z_rad"]]
    tgt = np.c_[design.bases["target_x_mm"], design.bases["target_y_mm"],
                design.bases["target_z_mm"]]
    layers = []
    for layer in LAYERS:
        posed = []
        for p in by_kind[("actuated", layer)]:
            r = row_of[p.base_id]
            A = np.eye(4)
            A[:3, :3] = rotvec_to_matrix(rot[r])
            A[:3, 3] = tgt[r] + A[:3, :3] @ [0.0, 0.0, layer_sign(layer) * SIM.membrane_h / 2]
            posed.append(solids[p.name].transform(affine_rows(A)))
        layers.append(union(posed))
    return union(layers)


def _export(design_dir: Path, outputs: dict, made_from: str) -> dict:
    """Write the STLs and ``stl/parts.json`` (what they were made from: the report lists
    them only while the tables match); returns :func:`describe_stl` per output."""
    info = {}
    with atomic_dir(design_dir / "stl") as tmp:
        for key, m in outputs.items():
            # drop the zero-area triangles and doubled vertices that a union of coplanar
            # faces can leave (they lie within manifold3d's ~1e-11 mm tolerance, so nothing
            # moves): written as float32 they made the STL non-manifold
            m = outputs[key] = m.simplify(EXPORT_SIMPLIFY_MM)
            as_float32(from_manifold(m)).export(str(tmp / STL_FILES[key]), file_type="stl")
            info[key] = describe_stl(tmp / STL_FILES[key], m)
        (tmp / Path(PARTS_RECORD).name).write_text(json_text(
            {"made_by": "morphshell render", "tables_sha256": made_from,
             "files": {STL_FILES[k]: hashlib.sha256((tmp / STL_FILES[k]).read_bytes())
                       .hexdigest() for k in outputs}}, indent=1))
    return info


def _log_rendered(res: dict, log) -> None:
    """What :func:`render_parts` did, and the parts the fast renderer left to OpenSCAD."""
    log(f"{res['renderer']} renderer ({res['renderer_version']}): {res['rendered']} rendered, "
        f"{res['cached']} cached, {res['wall_s']:.1f} s")
    if res["fallback"]:
        log(f"WARNING: the fast renderer failed on {len(res['fallback'])} parts, rendered by "
            f"OpenSCAD instead: {', '.join(sorted(res['fallback']))}")


def _warn_solids(info: dict, log) -> None:
    """Warn about a layer that is not one solid and an STL that is not watertight."""
    for layer in LAYERS:
        if info[layer]["bodies"] != 1:
            log(f"WARNING: the {layer} layer is {info[layer]['bodies']} separate solids, not one: "
                "some bases are not linked by brackets.")
    for key, v in info.items():
        if not v["watertight"]:
            log(f"WARNING: {STL_FILES[key]} is not watertight once written (float32 STL "
                "coordinates merged near-coincident vertices); a slicer's repair will fix it.")


def _render_summary(parts, res: dict, info: dict, design_dir: Path) -> dict:
    """The render stage's figures (:func:`render_design`), without timings and folders."""
    n_r = res["rendered"]
    return {
        "parts": len(parts),
        "parts_by_kind": {k: sum(p.kind == k for p in parts)
                          for k in ("node", "actuated", "frame", "marker")},
        "rendered": n_r,
        "cached": res["cached"],
        "seconds_per_part": (float(np.mean(list(res["seconds"].values()))) if n_r else None),
        "wall_seconds_per_part": (res["wall_s"] / n_r if n_r else None),
        "cpu_seconds_per_part": (res["cpu_s"] / n_r if n_r else None),
        "stl": {k: str(design_dir / "stl" / STL_FILES[k]) for k in info},
        "watertight": {k: v["watertight"] for k, v in info.items()},
        "bodies": {k: v["bodies"] for k, v in info.items()},
        "volumes_mm3": {k: v["volume_mm3"] for k, v in info.items()},
        "bbox_mm": {k: v["bbox_mm"] for k, v in info.items()},
        "triangles": {k: v["triangles"] for k, v in info.items()},
        "openscad": res["openscad"],
        "renderer": res["renderer"],
        "renderer_version": res["renderer_version"],
        "fallback_parts": sorted(res["fallback"]),
        "jobs": res["jobs"],
        "facet_tol_mm": TOL.facet,
        "layer_height_mm": UNIT_CELL.layer_h,
    }


__all__ = ["render_design", "assemble_layers", "STL_FILES", "EXPORT_SIMPLIFY_MM"]
