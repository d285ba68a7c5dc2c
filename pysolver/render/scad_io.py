"""Generated OpenSCAD part files: one ``.scad`` data file per part, from the tables.

The geometry lives in the OpenSCAD library ``scad/`` (``unit_node.scad``,
``bracket.scad``, ``bumper.scad``, ...), which users may edit.  This module
only turns the design tables (``bases.csv``, ``cells.csv``, ``bumpers.csv``,
``support_frame.csv``, ``stencil.obj``; see ``docs/design-folder.md``) into
*data*: each generated file ``use``s the library by absolute path, defines
nothing and calls one module once, e.g.::

    // morphshell part node_top_0007: base 7, top layer (flat shell frame)
    use </repo/scad/unit_node.scad>
    unit_node(centre=[10.5, 6.06217783], layer="top",
              bumpers=[[0, [2.8, 0, 1.3], [1, 0, 0]], ...],
              brackets=[[0, 7, 0.45], ...], alignment=false, marker=true);

Parts
-----
``node_<layer>_<base>``      base + bumpers + the whole bracket of every cell this base
                             owns (:func:`bracket_owner`: the lower base id) + pocket/hole,
                             flat shell frame
``actuated_<layer>_<base>``  the same node with its own two arms per cell, opened to the
                             target spans, about its base centre (render.py moves it to
                             its target pose)
``frame_<layer>``            support-frame ring with breakaway connectors, flat shell frame
``marker``                   one marker dot in the layer-local frame (instanced in Python)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError, refuse_first
from ..params import LAYERS, SUPPORT_FRAME, UNIT_CELL, layer_sign
from ..params import tol as TOL
from ..tables import read_design as _read

SCAD_DIR = Path(__file__).resolve().parents[2] / "scad"
"""The OpenSCAD library shipped with the repository."""


LIBRARY_FILES = ("params.scad", "util.scad", "base.scad", "bumper.scad", "bracket.scad",
                 "holes.scad", "unit_node.scad", "support_frame.scad", "label.scad",
                 "specimen.scad")


@dataclass(frozen=True)
class Part:
    """One OpenSCAD part file.

    Attributes
    ----------
    name : str
        File stem, e.g. ``node_top_0007``.
    kind : str
        ``node``, ``actuated``, ``frame``, ``marker`` (or ``specimen``, see
        :mod:`pysolver.render.specimens`).
    layer : str or None
        ``top``/``bottom`` (None for the marker dot, which serves both layers).
    base_id : int
        Base (stencil face) id, -1 for frame and marker parts.
    path : pathlib.Path
        The written ``.scad`` file.
    """

    name: str
    kind: str
    layer: str | None
    base_id: int
    path: Path

    def label(self) -> str:
        """Human-readable part name for messages: ``base 7, top layer (node_top_0007.scad)``."""
        what = {"node": f"base {self.base_id}, {self.layer} layer",
                "actuated": f"base {self.base_id}, {self.layer} layer, actuated pose",
                "frame": f"support frame, {self.layer} layer",
                "marker": "marker dot",
                "specimen": f"specimen {self.name}"}.get(self.kind, self.name)
        return f"{what} ({self.path.name})"


# --------------------------------------------------------------------------------------------
# SCAD literals


def scad_literal(value) -> str:
    """Deterministic OpenSCAD literal of a Python value (numbers as ``%.9g``).

    Parameters
    ----------
    value : bool, int, float, str, None, or (nested) sequence / numpy array of those

    Returns
    -------
    text : str
    """
    if value is None:
        return "undef"
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"cannot write non-finite number {v!r} to a SCAD file")
        text = f"{v:.9g}"
        return "0" if text == "-0" else text
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(scad_literal(v) for v in value) + "]"
    raise TypeError(f"no SCAD literal for {type(value).__name__}: {value!r}")


def part_text(title: str, library: Path, module: str, **kwargs) -> str:
    """Text of a generated part file: header, ``use <library>``, one call ``module(**kwargs)``.

    Parameters
    ----------
    title : str
        One-line description for the header comment.
    library : pathlib.Path
        Library file to ``use`` (absolute path).
    module : str
        Module to call.
    **kwargs
        Its arguments, written with :func:`scad_literal`.
    """
    return _header(title, library) + _call(module, **kwargs)


def _call(module: str, **kwargs) -> str:
    args = ",\n    ".join(f"{k}={scad_literal(v)}" for k, v in kwargs.items())
    return f"{module}(\n    {args});\n"


def _header(title: str, library: Path) -> str:
    return (f"// morphshell part {title}\n"
            "// Generated by pysolver.scad_io from the design tables: data and one module call.\n"
            "// Edit the geometry in the library, not here: each render rewrites this file.\n"
            f"use <{library.as_posix()}>\n")


# --------------------------------------------------------------------------------------------
# tables


def read_design(design_dir):
    """Read the tables the render stage needs (through :mod:`pysolver.tables`) and check them.

    Parameters
    ----------
    design_dir : path-like
        Design folder (``bases.csv``, ``cells.csv``, ``bumpers.csv``,
        ``support_frame.csv``, ``stencil.obj``, ...).

    Returns
    -------
    design : pysolver.tables.Design

    Raises
    ------
    InputError
        A file or column is missing, a bracket thickness is outside 0.30-0.65 mm
        (:func:`pysolver.tables.check_design`), or a central length is not printable.
    """
    design_dir = Path(design_dir)
    d = _read(design_dir)
    cells = d.cells  # thickness range: checked by pysolver.tables.check_design
    l = np.asarray(cells["central_length_mm"], float)
    refuse_first(~(l > UNIT_CELL.bracket_offset),
                 lambda i, _: f"{design_dir / 'cells.csv'}:{i + 2}: central_length_mm = "
                              f"{l[i]!r} is not above 2 base_r cos(alpha) = "
                              f"{UNIT_CELL.bracket_offset:.4f} mm (the bases would overlap).",
                 fix="re-run the design stage; the 2D scaling rule keeps every cell long enough.")
    if len(d.support) < 3:
        raise InputError(f"{design_dir / 'support_frame.csv'}: the outline has "
                         f"{len(d.support)} points, at least 3 are needed.",
                         fix="re-run the design stage.")
    return d


# --------------------------------------------------------------------------------------------
# per-part data


def _layer_centre_offset() -> float:
    """Distance of a layer's centre from the membrane plane, base_th/2 + base_p (1.3 mm)."""
    return UNIT_CELL.base_th / 2 + UNIT_CELL.base_p


def bracket_owner(base_a: int, base_b: int) -> int:
    """Base whose flat node draws the whole bracket of the cell (base_a, base_b): the lower id.

    Each cell's bracket has one owner per layer (the same base in both layers), so
    every bracket apex lies inside one part and the union of a layer never has to
    join two parts at an apex: the only joint is the far end of each V, anchored
    ``h`` deep inside the other base's disc (``scad/bracket.scad``).
    """
    return int(min(int(base_a), int(base_b)))


def node_arguments(design: dict, base_id: int, layer: str, *, actuated: bool = False) -> dict:
    """Keyword arguments of ``unit_node()`` for one base and layer.

    Parameters
    ----------
    design : pysolver.tables.Design
        Output of :func:`read_design`.
    base_id : int
        Base (stencil face) id.
    layer : str
        ``top`` or ``bottom``.
    actuated : bool
        Target pose (``pose`` and bracket spans) instead of the flat layout.

    Returns
    -------
    kwargs : dict
        ``centre`` (2,) mm, ``layer``, ``bumpers`` [[dir deg, (3,) mm, (3,)]],
        ``brackets`` [[dir deg, l mm, h mm(, span mm, fold deg)]] (flat: the cells whose bracket
        this base owns, :func:`bracket_owner`; actuated: every cell of the base, with
        its span), ``alignment``, ``marker``; flat: ``rim`` [[dir deg, l mm, h mm]] (every
        cell of the base, for the rotation of its polygon); actuated: ``pose``
        [(3,) rad, (3,) mm].
    """
    bases, cells, bumpers = design.bases, design.cells, design.bumpers
    s = layer_sign(layer)
    flat = np.column_stack([bases["flat_x_mm"], bases["flat_y_mm"]]).astype(float)
    tgt = np.column_stack([bases["target_x_mm"], bases["target_y_mm"],
                           bases["target_z_mm"]]).astype(float)
    nrm = np.column_stack([bases["normal_x"], bases["normal_y"], bases["normal_z"]]).astype(float)
    row = int(np.flatnonzero(np.asarray(bases["base_id"]) == base_id)[0])
    # bumpers of this base and layer, by slot
    sel = np.flatnonzero((np.asarray(bumpers["base_id"]) == base_id)
                         & (np.asarray(bumpers["layer"]) == layer))
    sel = sel[np.argsort(np.asarray(bumpers["slot"])[sel], kind="stable")]
    bump = [[float(bumpers["dir_deg"][k]),
             [float(bumpers["plane_px"][k]), float(bumpers["plane_py"][k]),
              float(bumpers["plane_pz"][k])],
             [float(bumpers["plane_nx"][k]), float(bumpers["plane_ny"][k]),
              float(bumpers["plane_nz"][k])]] for k in sel]
    # brackets by slot of this base: flat, only the cells this base owns (drawn whole);
    # actuated, every cell (this node's own opened arms)
    ba, bb = np.asarray(cells["base_a"]), np.asarray(cells["base_b"])
    entries, all_cells = [], []
    for c in np.flatnonzero((ba == base_id) | (bb == base_id)):
        mine_a = ba[c] == base_id
        nb = int(bb[c] if mine_a else ba[c])
        slot = int(cells["slot_a"][c] if mine_a else cells["slot_b"][c])
        nrow = int(np.flatnonzero(np.asarray(bases["base_id"]) == nb)[0])
        d = flat[nrow] - flat[row]
        entry = [math.degrees(math.atan2(d[1], d[0])), float(cells["central_length_mm"][c]),
                 float(cells[f"thickness_{layer}_mm"][c])]
        all_cells.append((slot, entry))
        if not actuated and bracket_owner(ba[c], bb[c]) != base_id:
            continue
        if actuated:
            # actuated span = 3D distance of this layer's centres (as the reference), kept
            # within [2 r cos(alpha), l] where the opened V exists (a preview must not fail)
            off = s * _layer_centre_offset()
            span = float(np.linalg.norm((tgt[nrow] + off * nrm[nrow])
                                        - (tgt[row] + off * nrm[row])))
            entry.append(float(np.clip(span, UNIT_CELL.bracket_offset + TOL.merge, entry[1])))
            entry.append(float(cells["fold_angle_deg"][c]))  # opened arms stop short by it
        entries.append((slot, entry))
    brackets = [e for _, e in sorted(entries, key=lambda se: se[0])]
    kw = dict(centre=flat[row], layer=layer, bumpers=bump, brackets=brackets,
              alignment=bool(int(bases["alignment"][row])), marker=True)
    if not actuated:
        # every cell of the base, owned or not: their V ends all cross this base's rim,
        # which sets the rotation of its polygon (scad/base.scad base_phase())
        kw["rim"] = [e[:3] for _, e in sorted(all_cells, key=lambda se: se[0])]
    if actuated:
        rv = [float(bases["rot_x_rad"][row]), float(bases["rot_y_rad"][row]),
              float(bases["rot_z_rad"][row])]
        kw["pose"] = [rv, tgt[row]]
    return kw


def frame_holes(outline, frame=SUPPORT_FRAME) -> list:
    """Holes of the ring's inner offset: places the frame ring must not be printed.

    The ring is ``offset(offset_out) - offset(offset_in)`` of the outline.  Where a notch
    of the outline is wider than ``2 offset_in`` inside but narrower at its mouth, the
    inner offset has a hole there, and the ring would get a loose island around it (a
    piece held by nothing).  These holes, each grown by ``frame.hole_margin`` so that
    they overlap the inner offset whatever its faceting, are filled by
    ``support_frame(holes=...)``.

    Parameters
    ----------
    outline : (b, 2) float, mm
    frame : pysolver.params.SupportFrame

    Returns
    -------
    holes : list of (k, 2) float arrays, mm (counter-clockwise)
    """
    import manifold3d  # heavy: manifold3d loads only for STL booleans

    P = np.asarray(outline, float)
    area = 0.5 * np.sum(P[:, 0] * np.roll(P[:, 1], -1) - np.roll(P[:, 0], -1) * P[:, 1])
    if area < 0:
        P = P[::-1]
    inner = manifold3d.CrossSection([P.tolist()], manifold3d.FillRule.Positive).offset(
        frame.offset_in, manifold3d.JoinType.Round, 2.0, frame.circle_segments)
    holes = []
    for c in inner.to_polygons():
        c = np.asarray(c, float)
        a = 0.5 * np.sum(c[:, 0] * np.roll(c[:, 1], -1) - np.roll(c[:, 0], -1) * c[:, 1])
        if a >= 0:  # an outer contour
            continue
        grown = manifold3d.CrossSection([c[::-1].tolist()], manifold3d.FillRule.Positive)
        for g in grown.offset(frame.hole_margin, manifold3d.JoinType.Round, 2.0,
                              frame.circle_segments).to_polygons():
            holes.append(np.asarray(g, float))
    return holes


def ring_reach(outline, centre, direction, edge_dist, frame=SUPPORT_FRAME, holes=()):
    """Length of a support-frame connector: from the base centre along ``direction`` to the
    middle of the frame ring, or None when the ring cannot be reached straight.

    The ring is the region between the offsets ``offset_in`` and ``offset_out`` of the flat
    outline, minus the filled holes (:func:`frame_holes`; ``scad/support_frame.scad``).
    Along the ray beyond the base's boundary edge the connector ends at the first point
    of the ring whose distance to the outline is ``(offset_in + offset_out) / 2``; the
    last ``(offset_out - offset_in) / 2 - step`` of the connector must lie in the ring.  A fixed
    length would end short of the ring in a concave notch of the outline, where the ring
    is farther than ``offset_out`` from the base's own edge.

    Parameters
    ----------
    outline : (b, 2) float, mm
        Flat boundary loop of the stencil (``support_frame.csv``).
    centre : (2,) float, mm
        Base centre.
    direction : (2,) float
        Unit outward normal of the base's boundary edge.
    edge_dist : float, mm
        Distance from the centre to that edge.
    frame : pysolver.params.SupportFrame
    holes : list of (k, 2) float arrays, mm
        Filled holes of the inner offset (:func:`frame_holes`), not part of the ring.

    Returns
    -------
    length : float, mm, or None
        Distance from the centre to the connector's end; None when the ray meets the
        outline's interior again (it would cross the shell, e.g. across a notch), or does
        not reach the ring within ``connector_max_reach`` beyond the edge.
    """
    from matplotlib.path import Path as _Path  # point-in-polygon (a dependency already)

    P = np.asarray(outline, float)
    c = np.asarray(centre, float)
    u = np.asarray(direction, float)
    s = edge_dist + np.arange(0.0, frame.connector_max_reach + frame.step, frame.step)
    X = c + s[:, None] * u
    A, B = P, np.roll(P, -1, axis=0)
    AB = B - A
    t = np.clip(np.einsum("kij,ij->ki", X[:, None] - A, AB) / np.sum(AB * AB, 1), 0.0, 1.0)
    dist = np.linalg.norm(X[:, None] - (A + t[..., None] * AB), axis=2).min(axis=1)
    in_hole = np.zeros(len(s), bool)
    for h in holes:
        in_hole |= _Path(np.asarray(h, float)).contains_points(X)
    target = 0.5 * (frame.offset_in + frame.offset_out)
    hit = np.flatnonzero((dist >= target) & (dist <= frame.offset_out) & ~in_hole)
    if not len(hit):
        return None
    k = int(hit[0])
    # (the first samples sit on the base's own edge: only a return into the outline counts)
    away = dist[: k + 1] > frame.step
    if np.any(_Path(P).contains_points(X[: k + 1][away])):
        return None
    # (one step less: straight out from an edge the distance grows exactly 1 mm per mm)
    tail = s >= s[k] - 0.5 * (frame.offset_out - frame.offset_in) + frame.step
    tail[k + 1:] = False
    if np.any((dist[tail] < frame.offset_in) | in_hole[tail]):
        return None
    return float(s[k])


def boundary_edges(design) -> list:
    """Every boundary base with its (first) boundary edge, in base order.

    Returns
    -------
    list of (base_id, centre (2,) mm, outward unit normal (2,), edge distance mm)
        The flat base centre, the outward normal of its boundary edge and the distance
        from the centre to the edge's line.
    """
    bases, cells, uv = design.bases, design.cells, design.UV
    interior: dict[int, set] = {}
    for a, b, sa, sb in zip(cells["base_a"], cells["base_b"], cells["slot_a"], cells["slot_b"],
                            strict=True):
        interior.setdefault(int(a), set()).add(int(sa))
        interior.setdefault(int(b), set()).add(int(sb))
    F = np.column_stack([bases["v0"], bases["v1"], bases["v2"]]).astype(int)
    out = []
    for row, bid in enumerate(np.asarray(bases["base_id"]).astype(int)):
        if not int(bases["boundary"][row]):
            continue
        free = [j for j in range(3) if j not in interior.get(int(bid), set())]
        if not free:
            continue
        c = np.array([float(bases["flat_x_mm"][row]), float(bases["flat_y_mm"][row])])
        j = free[0]
        p, q = uv[F[row, (j + 1) % 3]], uv[F[row, (j + 2) % 3]]
        e = (q - p) / np.linalg.norm(q - p)
        n = np.array([e[1], -e[0]])
        dist = float(np.dot(p - c, n))
        if dist < 0:
            n, dist = -n, -dist
        out.append((int(bid), c, n, dist))
    return out


def frame_connectors(design, frame=SUPPORT_FRAME, holes=None) -> list:
    """Support-frame connectors: boundary bases chosen greedily, each reaching the ring.

    A boundary base (in base order) gets a connector unless a base already connected lies
    within ``frame.spacing`` (flat distance).  The connector leaves the base perpendicular
    to its (first) boundary edge (:func:`boundary_edges`) and ends in the middle of the
    frame ring (:func:`ring_reach`); a base from which the ring cannot be reached straight
    (deep in a notch of the outline, or facing another part of the shell) gets none, and
    the next base is tried.

    Parameters
    ----------
    design : pysolver.tables.Design
    frame : pysolver.params.SupportFrame
    holes : list of (k, 2) float arrays, mm, optional
        :func:`frame_holes` of the outline (computed when not given).

    Returns
    -------
    connectors : list of [[x, y] mm, dir deg, length mm]
        Base centre, outward direction, distance from the centre to the connector's end.
    """
    outline = np.asarray(design.support, float)
    if holes is None:
        holes = frame_holes(outline, frame)
    chosen: list = []
    for _bid, c, n, dist in boundary_edges(design):
        if any(np.hypot(*(c - np.asarray(q[0]))) < frame.spacing for q in chosen):
            continue
        length = ring_reach(outline, c, n, dist, frame, holes)
        if length is None:
            continue
        chosen.append([c, math.degrees(math.atan2(n[1], n[0])), length])
    return chosen


# --------------------------------------------------------------------------------------------
# writing


def write_part_files(design_dir, out_dir, *, scad_dir=None, actuated: bool = True,
                     design=None) -> list[Part]:
    """Write one ``.scad`` data file per part into ``out_dir``.

    Parameters
    ----------
    design_dir : path-like
        Design folder (tables).
    out_dir : path-like
        Folder for the part files (created).
    scad_dir : path-like, optional
        OpenSCAD library folder (default: the repository's ``scad/``).
    actuated : bool
        Also write the actuated-pose node parts.
    design : pysolver.tables.Design, optional
        Already read tables (:func:`read_design`).

    Returns
    -------
    parts : list of Part
        In a fixed order: nodes (top, bottom), actuated nodes, frames, marker.
    """
    scad_dir = Path(scad_dir or SCAD_DIR).resolve()
    check_library(scad_dir)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    design = design if design is not None else read_design(design_dir)
    bases = design.bases
    ids = [int(b) for b in bases["base_id"]]
    parts: list[Part] = []

    def emit(name, kind, layer, base_id, text):
        path = out_dir / f"{name}.scad"
        with open(path, "w", newline="\n") as f:
            f.write(text)
        parts.append(Part(name, kind, layer, base_id, path))

    node_lib = scad_dir / "unit_node.scad"
    kinds = [("node", False)] + ([("actuated", True)] if actuated else [])
    for kind, act in kinds:
        for layer in LAYERS:
            for b in ids:
                name = f"{kind}_{layer}_{b:04d}"
                kw = node_arguments(design, b, layer, actuated=act)
                if act:
                    # The node is drawn about its base centre and placed in the target by
                    # render.py in float64 (p_target = t + R p): OpenSCAD's own output of a
                    # rotated solid is rounded differently per part, and faces that should
                    # be coplanar across parts would leave slivers in the union.
                    rv, t = kw.pop("pose")
                    kw["centre"] = [0.0, 0.0]
                    title = (f"{name}: base {b}, {layer} layer, actuated, about the base "
                             f"centre;\n//   placed by render.py at t + R(rv) p, rv = "
                             f"{scad_literal(rv)} rad, t = {scad_literal(t)} mm")
                else:
                    title = f"{name}: base {b}, {layer} layer (flat shell frame)"
                emit(name, kind, layer, b, _header(title, node_lib) + _call("unit_node", **kw))
    outline = np.asarray(design.support, float)
    holes = frame_holes(outline)
    connectors = frame_connectors(design, holes=holes)
    for layer in LAYERS:
        name = f"frame_{layer}"
        text = _header(f"{name}: support frame, {layer} layer (flat shell frame)",
                       scad_dir / "support_frame.scad")
        text += _call("support_frame", outline=outline, connectors=connectors, layer=layer,
                      **({"holes": holes} if holes else {}))
        emit(name, "frame", layer, -1, text)
    text = _header("marker: one marker dot (layer-local frame)", scad_dir / "holes.scad")
    text += "marker_dot();\n"
    emit("marker", "marker", None, -1, text)
    return parts


def check_library(scad_dir) -> Path:
    """Check that ``scad_dir`` holds the morphshell OpenSCAD library.

    Raises
    ------
    InputError
        If a library file is missing.
    """
    scad_dir = Path(scad_dir)
    missing = [f for f in LIBRARY_FILES if not (scad_dir / f).is_file()]
    if missing:
        raise InputError(f"OpenSCAD library folder {scad_dir} lacks {', '.join(missing)}.",
                         fix="point scad_dir at a copy of the repository's scad/ folder.")
    return scad_dir


__all__ = ["Part", "SCAD_DIR", "scad_literal", "part_text", "read_design",
           "bracket_owner", "node_arguments", "frame_connectors", "ring_reach", "frame_holes",
           "boundary_edges", "write_part_files",
           "check_library"]
