"""Simulation check report: is the simulated morph the designed one?

:func:`make_report` reads a design folder (``bases.csv``, ``cells.csv``,
``stencil.obj``, ``time_landscape.csv``, ``sim/frames.npz``; see
``docs/design-folder.md``), judges the morph with the one check
(:func:`sim.report.verdict.check_morph`) and writes ``<design_dir>/report/index.html``
(self-contained: every picture is embedded as a base64 data URI; the page comes from the
templates of :mod:`sim.report.html`) and ``report.json``, then prints the verdict
(PASS / WARN / FAIL with reasons).  The checks and their thresholds
(:class:`pysolver.params.ReportThresholds`) are explained in ``docs/report.md``.

Sections: verdict; final shape vs target (rigid Kabsch alignment of the base
centres, error in mm and % of the target size, base-normal orientation);
timing (simulated unit-cell completion vs the programmed t*); collisions along
the path (:mod:`sim.model.collisions`); solver health; shaded renders at chosen
times and an animated GIF; flat layout coloured by bracket thickness; time
landscape.

Run as ``python -m sim.report.report <design_dir>`` or ``morphshell report <dir>``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from pysolver.core.progress import Steps
from pysolver.core.records import finite, json_text
from pysolver.core.staging import atomic_dir
from pysolver.errors import InputError, MorphshellError
from pysolver.params import PHYSICS_DEFAULT, PICTURES, SCAN_AGREEMENT, ReportThresholds
from pysolver.tables import predicted_timing_sd, read_table, tables_sha256

from ..model.mechtest import bearing, dried_shell, recorded_material
from ..viewer import frame_alignments, viewer_data
from . import fabrication as fab
from . import plots as rp
from .html import page
from .load import SimData, load_sim
from .metrics import shape_rms_over_time
from .verdict import Check, check_morph

RENDERERS = ("auto", "pyvista", "matplotlib")


def make_report(design_dir, *, times=(0, 3, 30, 50, 80), thresholds=None, out_dir=None,
                progress=True, image_px=560, gif_frames=0, renderer="auto", build_info=None,
                viewer_frames=80) -> dict:
    """Check a simulated morph and write the HTML/JSON report.

    Parameters
    ----------
    design_dir : path-like
        Design folder with ``bases.csv``, ``cells.csv`` and ``sim/frames.npz``
        (``stencil.obj`` and ``time_landscape.csv`` are used when present).
    times : sequence of float, s
        Times of the still renders (nearest frame; the last frame is always added).
    thresholds : ReportThresholds or dict, optional
        Verdict limits (default :class:`~pysolver.params.ReportThresholds`).
    out_dir : path-like, optional
        Report folder (default ``<design_dir>/report``).  Written into a
        temporary folder beside it and moved into place when complete.
    progress : bool
        One line per step on stderr.
    image_px : int, px
        Width of the renders (height = 3/4); the GIF is at most 480 px wide.
    gif_frames : int
        Frames of an animated GIF written beside the report (at most 60; 0 = none, the
        default: the page embeds the interactive viewer instead).
    renderer : {"auto", "pyvista", "matplotlib"}
        Shell renderer; "auto" uses pyvista when off-screen rendering works.
    build_info : dict, optional
        ``source``, ``options``, ``inputs_sha256`` of the build (provenance).
    viewer_frames : int
        Frames of the embedded 3D viewer (evenly spaced, the end kept).

    Returns
    -------
    dict
        The content of ``report.json``: ``verdict``, ``reasons``, ``metrics``,
        ``thresholds``, ``files``, ``renderer``, ``timings_s``, ``out_dir``.

    Examples
    --------
    The check of the ``folder`` simulated in :func:`sim.model.simulate.simulate_design`'s
    example (small pictures drawn with matplotlib, to be quick):

    >>> from sim.report.report import make_report
    >>> r = make_report(folder, times=(0,), image_px=200, viewer_frames=5,
    ...                 renderer="matplotlib", progress=False)
    >>> r["verdict"] in ("PASS", "WARN", "FAIL"), (folder / "report" / "index.html").is_file()
    (True, True)
    """
    th = ReportThresholds.coerce(thresholds)
    gif_frames = _checked_options(renderer, image_px, gif_frames)
    t_start = time.perf_counter()
    sd = load_sim(design_dir)
    folder = sd.folder
    out_dir = Path(out_dir) if out_dir is not None else folder / "report"
    steps = Steps("report", folder.name, 6, enabled=progress, laps=True)
    timings = {"load": round(steps.step("loaded"), 3)}
    check = check_morph(sd.frames, sd.design, th, tables=_made_from(folder, sd.frames),
                        where=str(folder / "sim/frames.npz"))
    timings["check"] = round(steps.step("checks and verdict"), 3)
    notes = _notes(check.metrics, sd.frames)
    bears = what_it_bears(folder, build_info)
    with atomic_dir(out_dir) as tmp:
        files = _plots(tmp, sd, check, th)
        timings["plots"] = round(steps.step("plots"), 3)
        backend = _shell_pictures(tmp, sd, check, files, notes, times=times,
                                  image_px=int(image_px), gif_frames=gif_frames,
                                  renderer=renderer)
        timings["renders"] = round(steps.step(f"renders ({backend})"), 3)
        extra = _standalone(sd, check, tmp, folder, build_info, viewer_frames)
        files.update(extra.pop("files"))
        timings["standalone"] = round(steps.step("viewer, fabrication sheet, provenance"), 3)
        timings["total_before_write"] = round(time.perf_counter() - t_start, 3)
        t = sd.t
        result = finite({
            "design_dir": str(folder), "out_dir": str(out_dir), "verdict": check.verdict,
            "reasons": check.reasons, "metrics": check.metrics,
            "thresholds": dataclasses.asdict(th), "renderer": backend, "notes": notes,
            "files": files, "timings_s": timings,
            "render_frames": {"frames": files.get("render_frames", []),
                              "times_s": [float(t[f]) for f in files.get("render_frames", [])]},
            "provenance": extra["provenance"], "stls": extra["stls"], "bears": bears,
            "fabrication": extra["fabrication"],
            "timing_sd_predicted_s": _predicted_sd(folder, len(check.t_done))})
        (tmp / "report.json").write_text(json_text(result))
        (tmp / "index.html").write_text(page(result, tmp, folder.resolve().name,
                                             extra["viewer"]), encoding="utf-8")
        timings["write"] = round(steps.step("written"), 3)
    timings["total"] = round(time.perf_counter() - t_start, 3)
    result["timings_s"] = timings
    return result


def what_it_bears(folder, build_info: dict | None = None) -> dict:
    """The report's "What it bears" figures (:func:`sim.model.mechtest.bearing` on the last
    frame, dried; the bracket model the build ran with: ``build_info["options"]`` during a
    build, else the folder's ``summary.json``, else the committed one), or ``{"error": why}``
    when the shell cannot be loaded that way (odd or damaged frames: the section then says
    why, naming the exception and where it was raised; the report goes on).  Other
    exceptions (genuine bugs) propagate."""
    options = (build_info or {}).get("options")
    try:
        material = recorded_material(folder, options if isinstance(options, dict) else None)
        return bearing(dried_shell(folder, material, settle=False))
    except (MorphshellError, ValueError, RuntimeError, IndexError, KeyError,
            np.linalg.LinAlgError) as e:
        tb = e.__traceback__
        while tb is not None and tb.tb_next is not None:
            tb = tb.tb_next
        where = ("" if tb is None else
                 f" (at {Path(tb.tb_frame.f_code.co_filename).name}:{tb.tb_lineno})")
        return {"error": f"{type(e).__name__}: {e}{where}"}


def _checked_options(renderer, image_px, gif_frames) -> int:
    """Refuse a bad renderer or picture width; the GIF's frame count (0 or 2..60)."""
    if renderer not in RENDERERS:
        raise InputError(f"renderer = {renderer!r}", fix="use 'auto', 'pyvista' or 'matplotlib'")
    if not (16 <= int(image_px) <= 4096):
        raise InputError(f"image_px = {image_px}", fix="use a width between 16 and 4096 px")
    return 0 if not gif_frames else int(min(max(gif_frames, 2), 60))


def _made_from(folder: Path, frames: dict) -> dict:
    """What the report is made from: the tables now, and those the frames and STLs came from
    (the check's ``tables`` figures)."""
    made = frames.get("tables_sha256")
    return {"sha256": tables_sha256(folder),
            "frames_sha256": None if made is None else str(made),
            "parts": fab.parts_made_from(folder)}


def _notes(metrics: dict, frames: dict) -> list[str]:
    """The report's notes on how the frames were made (early stop, physics options) and what
    the check can promise (:data:`pysolver.params.SCAN_AGREEMENT`); the physics switched on
    also go into ``metrics["physics"]``."""
    notes = []
    if metrics.get("stopped_early"):
        # the simulator stops only when every cell rests on its bumpers in both layers and
        # nothing moved in a step: the bumpers then lock the shape, later times add nothing
        notes.append(f"The simulation settled at t = {metrics['t_end_s']:g} s (every unit cell "
                     "on its bumpers in both layers, no motion) and stopped there.")
    if "physics" in frames:  # effects beyond the reference model the frames were simulated with
        on = [k for k, v in json.loads(str(frames["physics"])).items() if v is True]
        if on:
            metrics["physics"] = on
            notes.append("Simulated with physics beyond the reference model: "
                         f"{', '.join(on)} (docs/physics.md).")
    promise = SCAN_AGREEMENT.promise()
    if set(metrics.get("physics") or ()) != set(PHYSICS_DEFAULT.switched_on()):
        promise += (" That was measured with the default physics, not with the physics of "
                    "this simulation.")
    notes.append(promise)
    return notes


def _predicted_sd(folder: Path, n_cells: int) -> dict | None:
    """Mean and max over cells of the predicted completion-time sd under the per-bracket
    thickness scatter (:func:`pysolver.tables.predicted_timing_sd`), or None."""
    sd = predicted_timing_sd(folder, n_cells)
    if sd is None or not np.isfinite(sd).any():
        return None
    ok = sd[np.isfinite(sd)]
    return {"mean": float(ok.mean()), "max": float(ok.max())}


def _plots(tmp: Path, sd: SimData, check: Check, th: ReportThresholds) -> dict:
    """The 2D plots of the report folder; returns ``{key: file name}``."""
    fr, n_ok = sd.frames, check.n_valid
    t = sd.t[:n_ok]
    t_last = float(sd.t[n_ok - 1])
    mc = check.membrane_base
    files = {
        "timing": rp.plot_timing(tmp / "timing.png", sd.cells["t_star_s"], check.t_done,
                                 t_last, clamped=sd.cells.get("clamped"),
                                 sd=predicted_timing_sd(sd.folder, len(check.t_done))).name,
        "clearance": rp.plot_clearance(
            tmp / "collisions.png", t, check.base_base.min_clearance,
            mc.min_clearance if mc is not None else None, th.collision_depth_mm,
            reach=check.base_base.extra["reach_mm"]).name}
    if check.metrics["solver"]["recorded"]:
        files["solver"] = rp.plot_solver(tmp / "solver.png", t, fr["newton_iterations"][:n_ok],
                                         fr["residual"][:n_ok], fr["wall_s"][:n_ok],
                                         fr["converged"][:n_ok], th.residual_fail_N).name
    rms_t = shape_rms_over_time(np.asarray(fr["base_center"], float)[:n_ok], sd.target)
    files["shape_over_time"] = rp.plot_shape_over_time(tmp / "shape_over_time.png", t, rms_t,
                                                       check.shape["size_mm"], th).name
    files["layout"] = rp.plot_layout_thickness(
        tmp / "layout_thickness.png", sd.flat_xy, sd.cell_pairs,
        sd.cells["thickness_top_mm"], sd.cells["thickness_bottom_mm"]).name
    files["landscape"] = rp.plot_time_landscape(
        tmp / "time_landscape.png", sd.flat_xy, sd.cell_pairs, sd.cells["t_star_s"],
        check.t_done, uv=sd.UV, faces=sd.F, landscape=sd.landscape, t_end=t_last).name
    return files


def _shell_pictures(tmp: Path, sd: SimData, check: Check, files: dict, notes: list, *,
                    times, image_px: int, gif_frames: int, renderer: str) -> str:
    """Shell renders (stills, error picture, first collision, GIF) into ``tmp`` and
    ``files``, each frame in the target frame by its own rigid fit (the camera sees the
    shell from the same side all along the morph).  A pyvista failure mid-way redoes them
    with matplotlib, noted in ``notes``.  Returns the renderer used."""
    fr, n_ok = sd.frames, check.n_valid
    C = np.asarray(fr["base_center"], float)[:n_ok]
    R = np.asarray(fr["base_rotation"], float)[:n_ok]
    M, tri = fr.get("membrane_vertices"), fr.get("membrane_triangles")
    Qs, ss = frame_alignments(C, sd.target)
    C_d = np.einsum("fij,fbj->fbi", Qs, C) + ss[:, None]
    R_d = np.einsum("fij,fbjk->fbik", Qs, R)
    M_d = np.einsum("fij,fvj->fvi", Qs, M[:n_ok]) + ss[:, None] if M is not None else None
    T_d = np.asarray(tri, np.int64) if tri is not None and M_d is not None else None
    ren = rp.ShellRenderer(C_d, R_d, M_d, T_d, normals=sd.target_normals,
                           size=(image_px, int(round(0.75 * image_px))), backend=renderer)
    args = (ren, tmp, check, sd.t, times, gif_frames, image_px, (Qs, ss))
    try:
        imgs = _render_all(*args)
    except Exception as e:  # pyvista failed mid-way: redo everything with matplotlib
        if ren.backend != "pyvista":
            raise
        notes.append(f"pyvista rendering failed ({type(e).__name__}: {e}); "
                     "fell back to matplotlib 3D")
        ren.backend = "matplotlib"
        imgs = _render_all(*args)
    if ren.backend == "matplotlib":
        notes.append((ren.note + "; " if ren.note else "")
                     + "renders use matplotlib 3D (no depth buffer: parts may be drawn "
                       "in the wrong order)")
    files.update(imgs)
    return ren.backend


def _nearest_frames(t, times):
    """Nearest frame per requested time, plus the last frame; de-duplicated, in time order."""
    t = np.asarray(t, float)
    idx = [int(np.argmin(np.abs(t - x))) for x in times] + [len(t) - 1]
    return sorted(set(idx))


def _render_all(ren, tmp, check: Check, t, times, gif_frames, w, align):
    """Still renders, error picture, collision picture and the GIF; returns their file names."""
    last = check.n_valid - 1
    sel = _nearest_frames(t[:last + 1], times)
    # each still framed on its own frame (the flat sheet is 2-4x the size of the target, so
    # one camera for all would leave the end shape small); the GIF keeps one camera.  No
    # label in the picture: the page's caption gives the time (one caption each)
    names = []
    for f in sel:
        names.append(f"render_f{f:04d}.png")
        rp.save_png(ren.images([f], fit="these", zoom=1.3)[0], tmp / names[-1])
    out = {"renders": names, "render_frames": sel}
    err = check.shape["err"]
    clim = (0.0, max(float(err.max()), PICTURES.colour_floor_mm))
    img = ren.images([last], base_scalars=err, clim=clim,
                     cmap="plasma", scalar_title="error (mm)", fit="these")[0]
    out["shape_error"] = rp.save_png(img, tmp / "shape_error.png").name
    if check.base_base.count:
        out["collision_frame"] = _collision_picture(ren, tmp, check.base_base, t, align)
    if not gif_frames:
        return out
    # animation: at most gif_frames frames, at most 480 px wide
    gw = min(w, 480)
    saved = ren.size
    ren.size = (gw, int(round(0.75 * gw)))
    try:
        gsel = sorted(set(np.linspace(0, last, min(gif_frames, last + 1)).round().astype(int)))
        gimgs = ren.images(gsel, labels=[f"t = {t[f]:5.1f} s" for f in gsel])
    finally:
        ren.size = saved
    out["animation"] = rp.save_gif(gimgs, tmp / "morph.gif").name
    return out


def _collision_picture(ren, tmp, bc, t, align) -> str:
    """The first base-base collision, whole shell and a 25 mm close-up side by side."""
    Qs, ss = align
    ev = bc.first()
    f = ev["frame"]
    hit = np.unique(bc.pairs[bc.first_frame == f].ravel())
    point = (np.asarray(ev["point_mm"]) @ Qs[f].T + ss[f])[None]
    label = f"first collision, t = {t[f]:g} s: bases {ev['pair'][0]} & {ev['pair'][1]}"
    over = ren.images([f], labels=[label + " (red)"], highlight=hit, fit="these",
                      extra_points=point)[0]
    # close-up: 25 mm box around the contact, seen from the first base's top side
    a = ev["pair"][0]
    box = (point[0] - 12.5, point[0] + 12.5)
    close = ren.images([f], labels=["close-up"], highlight=hit, fit=box,
                       normal=ren.R[f, a, :, 2], extra_points=point)[0]
    return rp.save_png(np.concatenate([over, close], axis=1), tmp / "collision_frame.png").name


def _stretch_template(folder: Path, tmp: Path, files: dict):
    """The membrane stretch template (SVG and PDF, 1:1) from ``support_frame.csv``, or None."""
    if not (folder / "support_frame.csv").exists():
        return None
    sf = read_table(folder, "support_frame")
    if len(sf["x_mm"]) < 3:
        return None
    template = fab.stretch_template(np.c_[sf["x_mm"], sf["y_mm"]])
    title = f"{folder.resolve().name}: membrane stretch template"
    (tmp / "stretch_template.svg").write_text(fab.template_svg(template, title),
                                              encoding="utf-8")
    files["stretch_template"] = "stretch_template.svg"
    fab.template_pdf(template, tmp / "stretch_template.pdf", title)
    files["stretch_template_pdf"] = "stretch_template.pdf"
    return template


def _standalone(sd: SimData, check: Check, tmp, folder, build_info, viewer_frames) -> dict:
    """Viewer data, stretch template, STL list, fabrication sheet and provenance."""
    files = {}
    parts = check.metrics["tables"]["parts"]
    viewer = viewer_data(sd, check.t_done, max_frames=int(viewer_frames))
    template = _stretch_template(folder, tmp, files)
    align = np.flatnonzero(np.asarray(sd.bases.get("alignment", np.zeros(sd.n_bases)), int))
    t_star = np.asarray(sd.cells["t_star_s"], float)
    t_done = check.t_done
    ok = np.isfinite(t_done)
    span = (float(np.min(t_done[ok])), float(np.max(t_done[ok]))) if ok.any() else None
    cell_xyz = sd.target[sd.cell_pairs].mean(axis=1)
    steps = fab.fabrication_steps(
        n_align=len(align), align_ids=align.tolist(),
        side=fab.top_layer_side(sd.target, sd.target_normals),
        template=template or {"device_d_mm": max(fab.FABRICATION.star_diameters_mm),
                              "fits": True},
        t_span=span, parts_problem=parts["problem"])
    fabrication = {"steps": [{"title": a, "text": b} for a, b in steps],
                   "timeline": fab.timeline(t_star, t_done, cell_xyz,
                                            sd.cells.get("clamped")),
                   "alignment_bases": align.tolist(),
                   "template": None if template is None else {
                       k: template[k] for k in ("device_d_mm", "fits", "tau", "sheet_mm",
                                                "marker_radius_mm", "shell_radius_mm")}}
    return {"files": files, "viewer": viewer,
            "stls": fab.stl_inventory(folder, parts),
            "provenance": fab.provenance(folder, build_info), "fabrication": fabrication}


def print_verdict(r, out_dir):
    """Print the verdict line, naming ``out_dir/index.html``, and its reasons and notes."""
    print(f"simulation check: {r['verdict']}  ({out_dir / 'index.html'})")
    for x in r["reasons"]:
        print(f"  {x['level']}: [{x['check']}] {x['message']}")
    for n in r["notes"]:
        print(f"  note: {n}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sim.report.report",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("design_dir")
    ap.add_argument("--out", default=None)
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument("--renderer", default="auto", choices=RENDERERS)
    a = ap.parse_args(argv)
    r = make_report(a.design_dir, out_dir=a.out, progress=not a.quiet, renderer=a.renderer)
    print_verdict(r, Path(a.out) if a.out else Path(a.design_dir) / "report")
    return 3 if r["verdict"] == "FAIL" else 0


__all__ = ["make_report", "print_verdict", "RENDERERS"]

if __name__ == "__main__":
    sys.exit(main())
