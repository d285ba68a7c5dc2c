"""What the report needs to stand alone: provenance, the STL list, the fabrication sheet
(Supplementary Note 5) and the membrane stretch template.

Everything is read from the design folder the earlier stages wrote (``design.json``,
``temporal.json``, ``sim/summary.json``, ``sim/refine.json``, ``summary.json`` of a
previous build, ``studio_landscape.json``, ``stl/``, ``support_frame.csv``); nothing
of the design stages is recomputed.
"""

from __future__ import annotations

import datetime as _dt
import html
from pathlib import Path

import numpy as np

from pysolver.core.provenance import package_versions, sha256_file
from pysolver.params import FABRICATION, MEMBRANE_MODEL_FILE, SIM, UNIT_CELL
from pysolver.params import tol as TOL
from pysolver.tables import LANDSCAPE_SOURCE, PARTS_RECORD, read_record, tables_sha256

STL_PURPOSE = {
    "top.stl": "top layer (bases, bumpers, brackets): print brackets-down; glued to the "
               "membrane's top face (+normal side of the target)",
    "bottom.stl": "bottom layer: print brackets-down; glued to the membrane's other face, "
                  "holes on the push pins",
    "markers_top.stl": "marker dots of the top layer, printed in a second colour into its "
                       "pockets (detected in 3D scans: morphshell compare-scan)",
    "markers_bottom.stl": "marker dots of the bottom layer (second colour)",
    "support_frame_top.stl": "support frame of the top layer: keeps it flat while gluing; "
                             "break the sprues off before the bath",
    "support_frame_bottom.stl": "support frame of the bottom layer",
    "actuated.stl": "preview of the target (morphed) shape: not printed",
}
def _studio_edits(record: dict) -> str:
    """The edits of a studio landscape record, counted by tool (``LANDSCAPE_SOURCE``)."""
    edits = record.get("edits")
    if not isinstance(edits, list) or not edits:
        return "no recorded edit (the landscape as it was)"
    counts: dict[str, int] = {}
    for e in edits:
        if isinstance(e, dict):
            key = " ".join(str(e[k]) for k in ("tool", "mode") if isinstance(e.get(k), str))
            counts[key or "edit"] = counts.get(key or "edit", 0) + 1
    return ", ".join(f"{n} x {k}" for k, n in sorted(counts.items()))


def provenance(folder, build_info=None) -> dict:
    """Where a build came from: input, options, landscape source, models, versions, date.

    Parameters
    ----------
    folder : path-like
        Design folder.
    build_info : dict, optional
        ``source``, ``options``, ``inputs_sha256`` of the build running this report
        (``pysolver.build`` passes them; a standalone report reads ``summary.json``).

    Returns
    -------
    dict of JSON-serialisable values (see the report's provenance table).
    """
    folder = Path(folder)
    design = read_record(folder / "design.json") or {}
    dopt = design.get("options", {})
    summ = read_record(folder / "summary.json") or {}
    info = dict(build_info or {})
    for k in ("source", "options", "inputs_sha256"):
        info.setdefault(k, summ.get(k))
    opts = dict(info.get("options") or {})
    source = info.get("source") or dopt.get("source")
    src_path = Path(str(source)) if source else None
    if src_path is not None and src_path.is_file():
        src_hash, src_kind = sha256_file(src_path), "file"
    else:
        src_hash = dopt.get("source_sha256_16")
        src_kind = dopt.get("source_kind", "builtin")
    temporal = (read_record(folder / "temporal.json") or {}).get("summary", {})
    refine = read_record(folder / "sim" / "refine.json") or {}
    sim_sum = read_record(folder / "sim" / "summary.json") or {}
    versions = package_versions()
    if (summ.get("versions") or {}).get("openscad"):
        versions["openscad"] = summ["versions"]["openscad"]
    return {
        "input": {"source": str(source) if source else None, "kind": src_kind,
                  "sha256": src_hash},
        "options": {**{k: v for k, v in dopt.items() if k not in ("params",)}, **opts},
        "unit_cell_params": dopt.get("params"),
        "build_inputs_sha256": info.get("inputs_sha256"),
        "landscape": _landscape_source(folder, design, opts, temporal),
        "stencil": _stencil_text((design.get("summary") or {}).get("remesh") or {}),
        "refine_rounds": refine.get("rounds", refine.get("iterations", opts.get("refine"))),
        "models": _models(temporal),
        "simulation": {k: sim_sum.get(k) for k in ("steps", "t_final_s", "stopped_early",
                                                    "wall_s") if k in sim_sum},
        "versions": versions,
        "date_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC"),
    }


def _landscape_source(folder: Path, design: dict, opts: dict, temporal: dict) -> str:
    """Where the time landscape came from: the studio, the shape, a file, ``--time``;
    and how the program stage mapped it onto the achievable times."""
    studio = read_record(folder / LANDSCAPE_SOURCE)
    time_opt = design.get("options", {}).get("time", opts.get("time"))
    if isinstance(studio, dict):
        land = "edited in morphshell studio: " + _studio_edits(studio)
    elif time_opt is None:  # the shape's own, a --time-file, or the automatic sequencing
        land = (design.get("summary", {}).get("time", {}).get("source")
                or "the shape's own landscape")
    else:
        land = f"TIME = {time_opt}"
    if temporal.get("landscape_rescaled"):
        r = temporal["landscape_rescaled"]
        land += (f"; mapped from {r['from_s'][0]:.0f}-{r['from_s'][1]:.0f} s onto the "
                 f"achievable {r['to_s'][0]:.0f}-{r['to_s'][1]:.0f} s")
        if r.get("min_span_s"):
            land += f" (kept at least {r['min_span_s']:.0f} s wide: sequenced parts apart)"
    return land


def _stencil_text(rem: dict) -> str | None:
    """The remeshed stencil in words (size, scaling, trade for the landscape), or None."""
    if not rem.get("remeshed"):
        return None
    stencil = (f"{rem.get('vertices')} vertices, 3D scaling {rem.get('scale3d')}, longest "
               f"flat cell {rem.get('max_cell_length_mm')} mm")
    tr = rem.get("trade") or {}
    if tr.get("taken"):
        stencil += (f"; traded for the landscape's times: {tr['vertices']} vertices at "
                    f"scaling {tr['scale3d']:.3f} would clamp ~"
                    f"{100 * tr['clamped_estimate']:.0f} % of the cells (estimate), "
                    f"{tr['to_vertices']} larger cells at {tr['to_scale3d']:.3f} ~"
                    f"{100 * tr['to_clamped_estimate']:.0f} %: the shell is "
                    f"{100 * (1 - tr['to_scale3d'] / tr['scale3d']):.1f} % smaller")
    return stencil


def _models(temporal: dict) -> dict:
    """The model files the build used, with their hashes."""
    models = {}
    mat = temporal.get("material_model")
    if mat and Path(mat).is_file():
        models["material (bracket) model"] = {"path": mat, "sha256": sha256_file(mat)}
    elif mat:
        models["material (bracket) model"] = {"path": mat, "sha256": None}
    if MEMBRANE_MODEL_FILE.is_file():
        corr = (temporal.get("membrane_correction") or {}).get("correction")
        models["membrane model"] = {"path": str(MEMBRANE_MODEL_FILE),
                                    "sha256": sha256_file(MEMBRANE_MODEL_FILE),
                                    "correction": corr}
    return models


# ------------------------------------------------------------------------------------ STLs


def _stl_stats(path: Path):
    """Triangles and bounding-box size (mm) of a binary STL (ASCII: via trimesh)."""
    data = path.read_bytes()
    if len(data) >= 84:
        n = int(np.frombuffer(data[80:84], "<u4")[0])
        if 84 + 50 * n == len(data):
            rec = np.frombuffer(data[84:], np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)),
                                                     ("a", "<u2")]), count=n)
            v = rec["v"].reshape(-1, 3)
            size = (v.max(axis=0) - v.min(axis=0)).tolist() if n else [0.0, 0.0, 0.0]
            return n, size
    import trimesh  # heavy: trimesh loads only for STL work

    m = trimesh.load(path, force="mesh")
    return len(m.faces), (m.bounds[1] - m.bounds[0]).tolist()


def parts_made_from(folder) -> dict:
    """Whether the STLs of ``<folder>/stl`` were made from the folder's current tables.

    The render stage records the :func:`pysolver.tables.tables_sha256` of the tables it read
    and the sha256 of every STL in ``stl/parts.json`` (:data:`pysolver.tables.PARTS_RECORD`).
    The STLs are *fresh* when that record exists, its tables hash is the folder's, and every
    STL is the one recorded: a later ``program``, a studio edit or a hand-edited table makes
    them stale, and they must not be printed.

    Returns
    -------
    dict
        ``tables_sha256`` (the folder's now), ``recorded_sha256`` (None without a record),
        ``n_stl``, ``fresh`` (bool; True when there is no STL at all) and ``problem`` (str or
        None: what is stale and why).
    """
    folder = Path(folder)
    now = tables_sha256(folder)
    stls = sorted(p.name for p in (folder / "stl").glob("*.stl"))
    rec = read_record(folder / PARTS_RECORD)
    recorded = rec.get("tables_sha256") if isinstance(rec, dict) else None
    out = {"tables_sha256": now, "recorded_sha256": recorded, "n_stl": len(stls),
           "fresh": True, "problem": None}
    if not stls:
        return out
    files = rec.get("files") if isinstance(rec, dict) else None
    if not isinstance(files, dict) or not isinstance(recorded, str):
        problem = (f"{PARTS_RECORD} is missing: nothing says which tables the STLs were "
                   "made from")
    elif recorded != now:
        problem = ("the STLs were made from other tables than the folder's now (cells.csv or "
                   "the landscape changed after the render stage)")
    else:
        changed = sorted(set(stls) ^ set(files)) + [
            n for n in stls if n in files and sha256_file(folder / "stl" / n) != files[n]]
        problem = (f"{', '.join('stl/' + n for n in changed[:3])} changed after the render "
                   "stage" if changed else None)
    out.update(fresh=problem is None, problem=problem)
    return out


def stl_inventory(folder, made_from=None) -> list[dict]:
    """Every STL of ``<folder>/stl``: name, bytes, triangles, size (mm) and what it is for;
    empty when they are stale (``made_from``: :func:`parts_made_from`, computed when None):
    parts older than the tables are never listed."""
    made_from = parts_made_from(folder) if made_from is None else made_from
    if not made_from["fresh"]:
        return []
    out = []
    for p in sorted((Path(folder) / "stl").glob("*.stl")):
        n, size = _stl_stats(p)
        out.append({"name": f"stl/{p.name}", "bytes": p.stat().st_size, "triangles": n,
                    "size_mm": [round(float(s), 1) for s in size],
                    "purpose": STL_PURPOSE.get(p.name, "part")})
    return out


# ------------------------------------------------------------------------- stretch template


def _offset(loop, delta):
    """Outward offset of a closed polygon (round joins), manifold3d's CrossSection."""
    import manifold3d as m3d  # heavy: manifold3d loads only for STL booleans

    cs = m3d.CrossSection([np.asarray(loop, float)]).offset(delta, m3d.JoinType.Round)
    polys = cs.to_polygons()
    return max((np.asarray(p) for p in polys), key=lambda p: abs(_area(p)))


def _area(p):
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def stretch_template(outline, *, tau=SIM.tau, fab=FABRICATION) -> dict:
    """The membrane stretch template: marker and outline positions on the unstretched sheet.

    The sheet is stretched ``tau`` times about the device centre; a point at radius r on
    the unstretched sheet lands at ``tau r``.  So the markers of a device of tip
    diameter D are drawn at radius ``D / (2 tau)``, and the shell's flat outline (and the
    cut line, ``cut_margin_mm`` outside it in the stretched state) at ``1 / tau`` scale.

    Parameters
    ----------
    outline : (k, 2) float, mm -- flat boundary loop of the shell (``support_frame.csv``)
    tau : float -- pre-stretch factor

    Returns
    -------
    dict: ``device_d_mm``, ``fits`` (bool), ``markers`` (n, 2) mm, ``outline`` and
    ``cut`` (k, 2) mm (unstretched sheet, centre at 0), ``sheet_mm`` (side of the sheet),
    ``shell_radius_mm`` (stretched).
    """
    loop = np.asarray(outline, float)
    centre = 0.5 * (loop.min(axis=0) + loop.max(axis=0))
    loop = loop - centre
    if _area(loop) < 0:
        loop = loop[::-1]
    cut = _offset(loop, fab.cut_margin_mm)
    r_need = float(np.linalg.norm(cut, axis=1).max()) + fab.sheet_wrap_mm
    fits = [d for d in fab.star_diameters_mm if d / 2 >= r_need]
    d = min(fits) if fits else max(fab.star_diameters_mm)
    ang = 2 * np.pi * np.arange(fab.star_teeth) / fab.star_teeth
    r = d / (2 * tau)
    return {"device_d_mm": float(d), "fits": bool(fits), "tau": float(tau),
            "markers": np.c_[r * np.cos(ang), r * np.sin(ang)], "marker_radius_mm": r,
            "outline": loop / tau, "cut": cut / tau,
            "sheet_mm": float(2 * (r + fab.sheet_wrap_mm)),
            "shell_radius_mm": float(np.linalg.norm(loop, axis=1).max())}


def template_svg(tp: dict, title: str, fab=FABRICATION) -> str:
    """The template as an SVG drawn at 1:1 (width/height in mm, viewBox in mm)."""
    s = tp["sheet_mm"]
    c = s / 2

    def pts(P):  # sheet coordinates, y up -> SVG y down
        return " ".join(f"{c + x:.3f},{c - y:.3f}" for x, y in P)

    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{s:.2f}mm" height="{s:.2f}mm" '
           f'viewBox="0 0 {s:.3f} {s:.3f}">',
           f"<title>{html.escape(title)}</title>",
           f'<rect x="0" y="0" width="{s:.3f}" height="{s:.3f}" fill="white" stroke="#999" '
           'stroke-width="0.2"/>',
           f'<circle cx="{c:.3f}" cy="{c:.3f}" r="{tp["marker_radius_mm"]:.3f}" fill="none" '
           'stroke="#bbb" stroke-width="0.2" stroke-dasharray="2,2"/>',
           f'<path d="M{c - 4:.3f},{c:.3f}H{c + 4:.3f}M{c:.3f},{c - 4:.3f}V{c + 4:.3f}" '
           'stroke="black" stroke-width="0.3"/>']
    for i, (x, y) in enumerate(tp["markers"]):
        out.append(f'<circle class="marker" data-i="{i}" cx="{c + x:.3f}" cy="{c - y:.3f}" '
                   f'r="{fab.marker_r_mm:g}" fill="black"/>')
    out.append(f'<polygon class="outline" points="{pts(tp["outline"])}" fill="#f2d39b" '
               'fill-opacity="0.5" stroke="#b07000" stroke-width="0.3"/>')
    out.append(f'<polygon class="cut" points="{pts(tp["cut"])}" fill="none" stroke="red" '
               'stroke-width="0.3" stroke-dasharray="1.5,1"/>')
    # 50 mm scale bar: check the print scale with a ruler
    y0 = s - 6
    out.append(f'<path d="M6,{y0:.3f}H56M6,{y0 - 2:.3f}V{y0 + 2:.3f}M56,{y0 - 2:.3f}'
               f'V{y0 + 2:.3f}" stroke="black" stroke-width="0.4"/>')
    fs = max(2.5, s / 60)
    lines = [title,
             f"unstretched sheet, print at 100 % (1:1): the bar is 50 mm. Stretch {tp['tau']:g}x "
             f"until the {len(tp['markers'])} dots sit on the teeth of a "
             f"{tp['device_d_mm']:.0f} mm star device.",
             "shell outline (orange) and cut line (red dashes, "
             f"{fab.cut_margin_mm:g} mm outside the shell once stretched)"]
    for k, text in enumerate(lines):
        out.append(f'<text x="4" y="{4 + fs * (k + 1) * 1.2:.3f}" font-size="{fs:.2f}" '
                   f'font-family="sans-serif">{html.escape(text)}</text>')
    out.append(f'<text x="58" y="{y0 + 1:.3f}" font-size="{fs:.2f}" '
               'font-family="sans-serif">50 mm</text>')
    out.append("</svg>")
    return "\n".join(out) + "\n"


def template_pdf(tp: dict, path, title: str, fab=FABRICATION):
    """The template as a one-page PDF at 1:1 (page = the sheet, axes in mm; matplotlib)."""
    import matplotlib  # optional heavy dependency: matplotlib loads only when a picture is drawn

    matplotlib.use("Agg")
    # optional heavy dependency: matplotlib loads only when a picture is drawn
    import matplotlib.pyplot as plt

    s = tp["sheet_mm"]
    fig = plt.figure(figsize=(s / 25.4, s / 25.4))
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_xlim(-s / 2, s / 2)
    ax.set_ylim(-s / 2, s / 2)
    ax.set_axis_off()
    pt = 72 / 25.4                                       # points per mm
    for P, kw in ((tp["outline"], dict(color="#b07000", lw=0.3 * pt)),
                  (tp["cut"], dict(color="red", lw=0.3 * pt, ls=(0, (1.5, 1))))):
        Q = np.vstack([P, P[:1]])
        ax.plot(Q[:, 0], Q[:, 1], **kw)
    ax.fill(tp["outline"][:, 0], tp["outline"][:, 1], color="#f2d39b", alpha=0.5, lw=0)
    # optional heavy dependency: matplotlib loads only when a picture is drawn
    from matplotlib.patches import Circle

    for x, y in tp["markers"]:
        ax.add_patch(Circle((x, y), fab.marker_r_mm, color="black"))
    ax.plot([-4, 4], [0, 0], "k", lw=0.3 * pt)
    ax.plot([0, 0], [-4, 4], "k", lw=0.3 * pt)
    y0 = -s / 2 + 6
    ax.plot([-s / 2 + 6, -s / 2 + 56], [y0, y0], "k", lw=0.4 * pt)
    ax.text(-s / 2 + 58, y0, "50 mm", fontsize=2.5 * pt, va="center")
    ax.text(-s / 2 + 4, s / 2 - 4, f"{title}: print at 100 % (1:1); stretch {tp['tau']:g}x "
            f"onto the {tp['device_d_mm']:.0f} mm star device", fontsize=2.5 * pt, va="top")
    fig.savefig(path, format="pdf")
    plt.close(fig)
    return Path(path)


# ----------------------------------------------------------------------- fabrication sheet


def timeline(t_star, t_done, cell_xyz, clamped=None, n_bins: int = 5) -> list[dict]:
    """Expected timeline per region: cells grouped by programmed time.

    Parameters
    ----------
    t_star, t_done : (n,) float, s -- programmed and simulated completion (NaN = never)
    cell_xyz : (n, 3) float, mm -- unit-cell centre in the target shape
    clamped : (n,) bool, optional
    n_bins : int -- groups (equal counts of cells, by t*)

    Returns
    -------
    list of dict per group: ``t_star_s`` [lo, hi], ``cells``, ``sim_median_s``,
    ``sim_range_s`` [lo, hi] or None, ``never``, ``where_mm`` (centroid), ``clamped``.
    """
    t_star = np.asarray(t_star, float)
    t_done = np.asarray(t_done, float)
    xyz = np.asarray(cell_xyz, float)
    cl = np.zeros(len(t_star), bool) if clamped is None else np.asarray(clamped, bool)
    order = np.argsort(t_star, kind="stable")
    out = []
    for grp in np.array_split(order, min(n_bins, max(len(order), 1))):
        if not len(grp):
            continue
        d = t_done[grp]
        ok = np.isfinite(d)
        out.append({"t_star_s": [float(t_star[grp].min()), float(t_star[grp].max())],
                    "cells": int(len(grp)),
                    "sim_median_s": float(np.median(d[ok])) if ok.any() else None,
                    "sim_range_s": [float(d[ok].min()), float(d[ok].max())] if ok.any() else None,
                    "never": int((~ok).sum()), "clamped": int(cl[grp].sum()),
                    "where_mm": np.round(xyz[grp].mean(axis=0), 1).tolist()})
    return out


def top_layer_side(target_centres, normals) -> str:
    """Whether the target normals (the top layer's side) point to the concave or convex side."""
    c = np.asarray(target_centres, float)
    n = np.asarray(normals, float)
    s = float(np.mean(np.sum(n * (c.mean(axis=0) - c), axis=1)))
    if abs(s) < TOL.orientation_rel * max(np.ptp(c, axis=0).max(), 1.0):
        return "the shape is nearly flat: either side"
    return ("the concave (inner) side of the target" if s > 0
            else "the convex (outer) side of the target")


def fabrication_steps(*, n_align, align_ids, side, template, fab=FABRICATION,
                      tau=SIM.tau, t_span=None, parts_problem=None) -> list[tuple[str, str]]:
    """The fabrication sheet of one shell (SI Note 5), as (title, text) steps;
    ``parts_problem`` (:func:`parts_made_from`'s ``problem``) puts a render step first."""
    pin = fab.pin_diameter_mm
    hole = 2 * UNIT_CELL.align_r
    dev = template["device_d_mm"]
    fit = "" if template["fits"] else (" The shell is larger than the largest device "
                                       f"({dev:.0f} mm) with the margins: use a larger one.")
    span = "" if t_span is None else f" Expect the first cells at ~{t_span[0]:.0f} s and the " \
                                     f"last at ~{t_span[1]:.0f} s (timeline below)."
    first = [] if not parts_problem else [
        ("Render again", f"Do not print the STLs now in stl/: {parts_problem}. Render them "
                         "from these tables first (morphshell render DIR).")]
    return first + [
        ("Print", "Print stl/top.stl and stl/bottom.stl brackets-down, each with its support "
                  "frame (stl/support_frame_*.stl) and the marker dots (stl/markers_*.stl) in a "
                  "second colour. Remove the overhang support material (scrape, then blow "
                  "air through the lattice)."),
        ("Stretch", f"Print stretch_template.svg at 100 % and copy its {fab.star_teeth} dots and "
                    "the shell outline onto the unstretched latex sheet. Wrap the sheet around "
                    f"the teeth of the {dev:.0f} mm star device until every dot sits on a tooth "
                    f"tip: a uniform stretch of {tau:g}x ({tau ** 2:g}x the area)." + fit),
        ("Clean and glue", "Clean both faces of the sheet with 2-propanol. Spread super glue "
                           "thinly on a plastic film with a brush and transfer it to the "
                           "printed layer by contact."),
        ("Top layer", "Glue the top layer (stl/top.stl) onto the sheet inside the drawn "
                      f"outline. The top layer ends on {side}. Push pins (shaft Ø {pin:g} mm) "
                      f"through the {n_align} alignment holes (Ø {hole:g} mm, bases "
                      f"{', '.join(map(str, align_ids))}) and through the membrane."),
        ("Bottom layer", "Glue the bottom layer (stl/bottom.stl) on the other face of the "
                         "sheet, its alignment holes on the same pins. Glue the latex around "
                         "the lattice perimeter."),
        ("Release and cut", f"Wait {fab.glue_wait_min:g} min, release the sheet to a stretch "
                            f"near {fab.release_stretch:g}x, then cut the shell out with a "
                            "scalpel along the red line, leaving a thin border of latex so "
                            "the membrane does not tear. Break off the support frames."),
        ("Morph", f"Submerge the shell in water at {fab.water_c:g} °C and wait for the morph "
                  "to complete." + span),
        ("Dry", f"Take it out and let it dry (about {fab.dry_min:g} min)."),
    ]


__all__ = ["provenance", "stl_inventory", "parts_made_from", "stretch_template", "template_svg",
           "template_pdf", "timeline",
           "top_layer_side", "fabrication_steps", "STL_PURPOSE"]
