"""The report page, ``index.html``, filled in from the template files in ``templates/``.

Every piece of markup is a template file (:class:`string.Template` syntax, ``$name``): the
page, one file per section, and small fragments (a figure, a table row, a list item).
:func:`fill` inserts values escaped unless they are :class:`Markup` (the output of another
fill), so text from the design folder never becomes markup.  Pictures are embedded as
base64 data URIs: the page stands alone.  The sections and their order are
:data:`SECTIONS`.
"""

from __future__ import annotations

import base64
import functools
import html
import json
import math
from pathlib import Path
from string import Template

import numpy as np

from pysolver.params import MECHTEST, UNCERTAINTY, UNIT_CELL

from ..viewer import asset_text, viewer_json

TEMPLATES = Path(__file__).resolve().parent / "templates"
"""The template files of the page."""

SECTIONS = ("verdict", "viewer", "shape", "timing", "collisions", "solver", "bears", "renders",
            "layout", "landscape", "fabrication", "stls", "provenance")
"""Section ids of ``index.html``, in order."""


class Markup(str):
    """Text that is already HTML (a filled template): inserted as it is."""


@functools.cache
def _template(name: str) -> Template:
    text = (TEMPLATES / name).read_text(encoding="utf-8")
    return Template(text[:-1] if text.endswith("\n") else text)


def fill(template: str, /, **values) -> Markup:
    """The template ``templates/<template>.html`` with ``values`` in place.

    Values that are :class:`Markup` go in as they are; anything else is escaped text.
    The file's last newline is not part of the fragment.
    """
    safe = {k: v if isinstance(v, Markup) else html.escape(str(v)) for k, v in values.items()}
    return Markup(_template(f"{template}.html").substitute(safe))


def join(items, sep: str = "") -> Markup:
    """Fragments joined into one."""
    return Markup(sep.join(items))


def figure(folder, name: str, caption: str) -> Markup:
    """A picture of the report folder, embedded, with its caption."""
    p = Path(folder) / name
    mime = {".gif": "image/gif", ".svg": "image/svg+xml"}.get(p.suffix, "image/png")
    data = base64.b64encode(p.read_bytes()).decode("ascii")
    return fill("figure", mime=mime, data=Markup(data), caption=caption, file=name)


def figures(*items, wide: bool = False) -> Markup:
    """Pictures side by side (``wide``: one per row)."""
    return fill("figures", wide=" wide" if wide else "", items=join(items))


def _cell_text(v) -> str:
    if isinstance(v, float):
        return "n/a" if not math.isfinite(v) else f"{v:.4g}"
    return "n/a" if v is None else str(v)


def table(rows, head=None) -> Markup:
    """A table of ``rows`` (sequences of values); without ``head`` the first column is a
    header column.  Floats show 4 significant digits, None and non-finite as ``n/a``."""
    out = []
    if head:
        out.append(fill("row", cells=join(fill("head_cell", value=h) for h in head)))
    for row in rows:
        cells = [fill("head_cell" if k == 0 and not head else "cell", value=_cell_text(v))
                 for k, v in enumerate(row)]
        out.append(fill("row", cells=join(cells)))
    return fill("table", rows=join(out, "\n"))


def _f(x, fmt="{:.3g}"):
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else fmt.format(x)


def _fmt_bytes(n):
    return f"{n / 1e6:.2f} MB" if n >= 1e6 else f"{n / 1e3:.1f} kB"


def page(r: dict, folder, name: str, viewer=None) -> str:
    """``index.html`` of a report.

    Parameters
    ----------
    r : dict
        The content of ``report.json`` (:func:`sim.report.make_report`).
    folder : path-like
        The report folder being written (its pictures are embedded).
    name : str
        The design's name (the page title).
    viewer : dict, optional
        The 3D viewer's data (:func:`sim.viewer.viewer_data`); None: no viewer.
    """
    m = r["metrics"]
    sections = [_verdict(r), fill("section_viewer", viewer=_viewer(viewer)),
                _shape(m, r["thresholds"], r["files"], folder),
                _timing(m, r["thresholds"], r["files"], folder, r.get("timing_sd_predicted_s")),
                _collisions(m, r["thresholds"], r["files"], folder),
                _solver(m, r["thresholds"], r["files"], folder), _bears(r.get("bears")),
                _renders(r, folder), _flat_pictures(r["files"], folder),
                _fabrication(r, folder), _stls(r), _provenance(r)]
    links = join((fill("section_link", id=s) for s in SECTIONS), ", ")
    return fill("page", name=name, css=Markup((TEMPLATES / "report.css").read_text()),
                n_bases=m["n_bases"], n_cells=m["n_cells"], n_frames=m["n_frames"],
                t_end=f"{m['t_end_s']:g}", renderer=r["renderer"], links=links,
                sections=join(sections, "\n")) + "\n"


def _verdict(r: dict) -> Markup:
    reasons = join(fill("reason", **x) for x in r["reasons"]) or fill("no_reasons")
    return fill("section_verdict", verdict=r["verdict"], reasons=reasons,
                notes=join(fill("note", text=n) for n in r["notes"]))


def _viewer(viewer) -> Markup:
    if viewer is None:
        return Markup("")
    return fill("viewer_embed", viewer_css=Markup(asset_text("viewer.css")),
                three_js=Markup(asset_text("three.min.js")),
                viewer_js=Markup(asset_text("morph_viewer.js")),
                viewer_json=Markup(viewer_json(viewer)))


def _shape(m: dict, th: dict, fl: dict, folder) -> Markup:
    sh, fo = m["shape"], m["fold"]
    rows = [("RMS distance", f"{_f(sh['rms_mm'])} mm ({_f(sh['rms_pct'])} %)"),
            ("max distance", f"{_f(sh['max_mm'])} mm ({_f(sh['max_pct'])} %), "
                             f"base {sh['worst_base']}"),
            ("target size", f"{_f(sh['size_mm'])} mm"),
            ("base normal error", f"RMS {_f(sh['normal_rms_deg'])} deg, max "
                                  f"{_f(sh['normal_max_deg'])} deg"),
            ("fold angle error per cell",
             f"RMS {_f(fo['rms_deg'])} deg, max {_f(fo['max_deg'])} deg; "
             f"{fo['n_flipped']} of {fo['n_folded']} folded cells fold the wrong way"),
            ("limits", f"WARN > {th['shape_rms_warn_pct']} %, FAIL > "
                       f"{th['shape_rms_fail_pct']} % RMS; normals WARN > "
                       f"{th['normal_warn_deg']} deg, FAIL > {th['normal_fail_deg']} deg; "
                       f"folds WARN RMS > {th['fold_rms_warn_deg']} deg or any flipped, FAIL > "
                       f"{100 * th['fold_flip_fail_fraction']:g} % flipped")]
    pics = figures(figure(folder, fl["shape_error"], f"final shell (t = {m['t_end_s']:g} s) in "
                                                     "the target frame, bases coloured by their "
                                                     "distance to the target (mm)"),
                   figure(folder, fl["shape_over_time"], "RMS distance of the base centres to "
                                                         "the target over time, each frame "
                                                         "aligned rigidly"))
    return fill("section_shape", table=table(rows), figures=pics)


def _predicted_sd_row(pred: dict | None) -> list:
    """The table row of the cells' predicted timing sd under the thickness scatter
    (``report.json`` → ``timing_sd_predicted_s``; none when the design has no record)."""
    if not pred:
        return []
    return [(f"predicted completion sd of a print, bracket thickness sd "
             f"{UNCERTAINTY.thickness_sd:g} mm: mean / max over cells (bars in the plot)",
             f"{_f(pred['mean'])} / {_f(pred['max'])} s")]


def _timing(m: dict, th: dict, fl: dict, folder, pred: dict | None = None) -> Markup:
    tm = m["timing"]
    never = ", ".join(map(str, tm["never_due_cells"][:20])) or "none"
    rows = [("completed cells", f"{tm['n_completed']} / {tm['n_cells']}"),
            ("never completed (t* <= t_end)", f"{tm['n_never_due']}: {never}"),
            ("RMS error vs t*, all cells", f"{_f(tm['rms_all_s'])} s"),
            ("mean error (bias), all cells", f"{_f(tm.get('bias_all_s'), '{:+.3g}')} s"),
            ("Spearman rank correlation, all cells", _f(tm["spearman_all"])),
            ("cells clamped by the temporal stage", f"{tm['n_clamped']}"),
            ("RMS error vs t*, programmable cells", f"{_f(tm['rms_s'])} s"),
            ("mean error (bias), programmable cells", f"{_f(tm['bias_s'], '{:+.3g}')} s"),
            ("max |error|, programmable cells", f"{_f(tm['max_abs_s'])} s"),
            ("Spearman rank correlation, programmable cells", _f(tm["spearman"])),
            *_predicted_sd_row(pred),
            ("limits", f"WARN RMS > {th['timing_rms_warn_s']} s, Spearman < "
                       f"{th['spearman_warn']}, any never-completed cell; FAIL > "
                       f"{100 * th['incomplete_fail_fraction']:g} % never completed")]
    pics = figures(figure(folder, fl["timing"], "simulated completion vs programmed t*: "
                                                "programmable cells as dots, clamped cells as "
                                                "open squares, never-completed cells as red "
                                                "crosses on the t_end line"))
    return fill("section_timing", source=tm["source"],
                n_programmable=tm["n_cells"] - tm["n_clamped"],
                h_min=f"{UNIT_CELL.thickness_min:.2f}", h_max=f"{UNIT_CELL.thickness_max:.2f}",
                table=table(rows), figures=pics)


def _collisions(m: dict, th: dict, fl: dict, folder) -> Markup:
    co = m["collisions"]
    bb = co["base_base"]
    rows = [("base vs base (non-neighbours)",
             "none" if not bb["count"] else
             f"{bb['count']} pairs, first bases {bb['first']['pair']} at t = "
             f"{bb['first']['time_s']:g} s, point {np.round(bb['first']['point_mm'], 2).tolist()}"
             f" mm, max depth {bb['max_depth_mm']:.3g} mm"),
            ("closest approach (base vs base)", f"{_f(bb['min_clearance_mm'])} mm"
             if bb["min_clearance_mm"] is not None else
             f"no non-neighbouring pair came within {bb['reach_mm']:.1f} mm (centres)")]
    mb = co.get("membrane_base")
    if mb:
        rows.append(("membrane vs far base",
                     "none" if not mb["count"] else
                     f"{mb['count']} vertex/base pairs, first vertex {mb['first']['pair'][0]} "
                     f"in base {mb['first']['pair'][1]} at t = {mb['first']['time_s']:g} s"))
    else:
        rows.append(("membrane vs far base", "not checked (no membrane in frames.npz)"))
    pics = [figure(folder, fl["clearance"], "smallest clearance between parts per frame")]
    if "collision_frame" in fl:
        pics.append(figure(folder, fl["collision_frame"], "first collision: the colliding "
                                                          "bases in red, and a close-up"))
    return fill("section_collisions", base_r=f"{UNIT_CELL.base_r:g}",
                height=f"{2 * UNIT_CELL.layer_h:g}", depth=th["collision_depth_mm"],
                table=table(rows), figures=figures(*pics))


def _solver(m: dict, th: dict, fl: dict, folder) -> Markup:
    so = m["solver"]
    if not so["recorded"]:
        return fill("section_solver", body=fill("solver_none"))
    times = (f"(t = {', '.join(f'{x:g}' for x in so['nonconverged_times_s'][:20])} s)"
             if so["n_nonconverged"] else "")
    rows = [("steps", so["n_steps"]),
            ("Newton iterations", f"total {so['iterations_total']}, mean "
                                  f"{_f(so['iterations_mean'])}, max {so['iterations_max']}"),
            ("largest residual", f"{_f(so['residual_max'])} N"),
            ("wall time", f"total {_f(so['wall_total_s'])} s, mean {_f(so['wall_mean_s'])} s, "
                          f"max {_f(so['wall_max_s'])} s"),
            ("non-converged steps", f"{so['n_nonconverged']} " + times),
            ("limit", f"FAIL if a non-converged step ends above {th['residual_fail_N']} N, "
                      "else WARN")]
    pics = figures(figure(folder, fl["solver"], "Newton iterations, residual and wall time per "
                                                "step"))
    return fill("section_solver", body=join([table(rows), pics]))


def _bears(b) -> Markup:
    """The "What it bears" section (:func:`sim.model.mechtest.bearing`, with the uncertainty
    of :data:`pysolver.params.MECHTEST`'s comparison with the printed shell)."""
    if not b or "error" in b:
        why = (b or {}).get("error", "not computed")
        return fill("section_bears", supports="-", apex="-", table=table([("not computed",
                                                                             why)]),
                    note=Markup(""))

    def force(x):
        return "not within the model's range" if x is None else f"{x:.3g} N"

    rows = [("point load: stiffness", f"{_f(b['point_stiffness_N_per_mm'])} N/mm"),
            ("point load at which a cell opens", force(b["cell_opens_N"])),
            ("point load at which a bracket leaves its tested load "
             f"({MECHTEST.bracket_yield_N:g} N)", force(b["bracket_limit_N"])),
            ("own weight", f"{_f(b['weight_N'])} N: largest sag {_f(b['weight_sag_mm'])} mm "
                           f"({_f(b['weight_stiffness_N_per_mm'])} N/mm)")]
    lo, hi = MECHTEST.slope_error
    plo, phi = MECHTEST.peak_error
    note = fill("note", text=f"Uncertainty: on SI Note 6's printed specimen the same model "
                             f"predicted the initial stiffness {100 * lo:+.0f} % to "
                             f"{100 * hi:+.0f} % off the measured, and the peak stresses "
                             f"{100 * plo:+.0f} % to {100 * phi:+.0f} % (stretching and "
                             f"bending, docs/results.md): read the stiffnesses as good to a "
                             f"factor of about {1 + max(-lo, hi):.1f}, the loads to about "
                             f"{100 * max(-plo, phi):.0f} %; first-order figures (small "
                             "loads), on one flat specimen's evidence.")
    return fill("section_bears", supports=b["n_supports"], apex=b["apex_base"],
                table=table(rows), note=note)


def _renders(r: dict, folder) -> Markup:
    fl = r["files"]
    times = r["render_frames"]["times_s"]
    pics = [figure(folder, n, f"t = {x:g} s" + (" (end)" if k == len(fl["renders"]) - 1 else ""))
            for k, (n, x) in enumerate(zip(fl["renders"], times, strict=True))]
    return fill("section_renders", times=str(list(times)), figures=figures(join(pics)))


def _flat_pictures(fl: dict, folder) -> Markup:
    layout = figures(figure(folder, fl["layout"], "bracket thickness per unit cell, top and "
                                                  "bottom layer"), wide=True)
    land = figures(figure(folder, fl["landscape"], "programmed time landscape on the flat "
                                                   "stencil, and the simulated completion per "
                                                   "cell on the same colour scale"), wide=True)
    return join([fill("section_layout", figures=layout),
                 fill("section_landscape", figures=land)], "\n")


def _fabrication(r: dict, folder) -> Markup:
    fab = r.get("fabrication") or {}
    steps = join(fill("step", title=s["title"], text=s["text"]) for s in fab.get("steps", []))
    rows = []
    for g in fab.get("timeline", []):
        lo, hi = g["t_star_s"]
        sim = ("never" if g["sim_range_s"] is None else
               f"{g['sim_range_s'][0]:.0f}-{g['sim_range_s'][1]:.0f} s "
               f"(median {g['sim_median_s']:.0f} s)")
        rows.append((f"{lo:.0f}-{hi:.0f} s", g["cells"], sim, g["never"], g["clamped"],
                     "({:.0f}, {:.0f}, {:.0f})".format(*g["where_mm"])))
    timeline = table(rows, head=("programmed t*", "cells", "simulated completion", "never",
                                 "clamped", "where: centre of the group in the target (x, y, z) "
                                            "mm"))
    tpl = fab.get("template")
    stretch = Markup("")
    if tpl and "stretch_template" in r["files"]:
        pic = figures(figure(folder, r["files"]["stretch_template"],
                             "the template (reduced here; the file is 1:1)"))
        stretch = fill("stretch_template", device_d=f"{tpl['device_d_mm']:.0f}",
                       marker_r=f"{tpl['marker_radius_mm']:.1f}", tau=f"{tpl['tau']:g}",
                       figures=pic)
    return fill("section_fabrication", steps=steps, timeline=timeline, template=stretch)


def _stls(r: dict) -> Markup:
    stls = r.get("stls") or []
    parts = ((r.get("metrics") or {}).get("tables") or {}).get("parts") or {}
    if not parts.get("fresh", True):
        body = fill("stls_stale", problem=parts["problem"])
    elif not stls:
        body = fill("stls_none")
    else:
        body = table([(s["name"], _fmt_bytes(s["bytes"]), s["triangles"],
                       " x ".join(f"{v:g}" for v in s["size_mm"]), s["purpose"])
                      for s in stls],
                     head=("file", "size", "triangles", "extent (mm)", "what it is for"))
    return fill("section_stls", body=body)


def _provenance(r: dict) -> Markup:
    p = r.get("provenance") or {}
    inp = p.get("input") or {}
    rows = [("input", f"{inp.get('source')} ({inp.get('kind')})"),
            ("input sha256", inp.get("sha256")),
            ("build inputs sha256", p.get("build_inputs_sha256")),
            ("time landscape", p.get("landscape")),
            ("stencil", p.get("stencil")),
            ("refinement rounds", p.get("refine_rounds"))]
    for k, v in (p.get("models") or {}).items():
        rows.append((k, f"{v.get('path')} (sha256 {v.get('sha256')})"
                        + (f", correction {v['correction']}" if v.get("correction") else "")))
    for k, v in sorted((p.get("options") or {}).items()):
        rows.append((f"option {k}", json.dumps(v) if not isinstance(v, str) else v))
    if p.get("unit_cell_params"):
        rows.append(("unit-cell parameters", json.dumps(p["unit_cell_params"])))
    for k, v in (p.get("simulation") or {}).items():
        rows.append((f"simulation {k}", v))
    rows.append(("versions", ", ".join(f"{k} {v}" for k, v in (p.get("versions") or {}).items())))
    rows.append(("report date", p.get("date_utc")))
    return fill("section_provenance", table=table(rows))


__all__ = ["SECTIONS", "TEMPLATES", "Markup", "fill", "figure", "figures", "table", "page"]
