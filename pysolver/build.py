"""The whole pipeline for one shape: design -> program -> simulate [-> contact] [-> refine]
-> render -> report.  (``contact``: simulated again with barrier contact when far-apart parts
passed through each other, :func:`_contact_if_needed`.)

``build(shape)`` runs every stage in a staging folder ``build/.staging/<name>``
and moves it to ``build/<name>`` only when all stages have finished, so an
interrupted build leaves the previous complete result (or nothing).  The staging
folder survives an interruption: a re-run with the same inputs reuses it, which
lets the simulation resume from its last checkpoint.  A lock per shape keeps two
builds of the same shape apart; different shapes build concurrently.

Every build writes ``summary.json`` with its key figures (counts, sizes,
thickness range, check results, timings), the versions of the project,
OpenSCAD and key libraries, and a hash of the inputs.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from sim.model.collisions import never_due, open_layers
from sim.model.physics import parse_physics
from sim.model.simulate import SimSettings, simulate_design, simulate_model, simulated_completion
from sim.report import (
    base_base_collisions,
    check_frames,
    completion_times,
    load_sim,
    make_report,
    print_verdict,
)
from sim.report.plots import start_pyvista_probe
from sim.viewer import ASSETS as VIEWER_ASSETS
from sim.viewer import STATIC_DIR as VIEWER_DIR
from sim.viewer import viewer_data

from . import tables
from .atomic import (
    atomic_dir,
    atomic_write_text,
    build_lock,
    claim_output,
    public_mode,
    recover_stale,
    remove_staging,
    replace_dir,
    staging_dir,
    write_stamp,
)
from .design import check_design_options, run_design
from .design.surfaces import BUILTIN_SHAPES, check_spec
from .design.time_landscape import read_time_file
from .errors import EXIT_CHECK_FAILED, EXIT_OK, InputError, MorphshellError
from .material.model import DEFAULT_MODEL_PATH, check_bracket_geometry, load_bracket_model
from .params import DEFAULT_REFINE, LIMITS, MODEL_LIMITS, REPORT, SIM, UNIT_CELL
from .render import (
    DEFAULT_RENDERER,
    check_renderer,
    find_openscad,
    render_design,
    start_self_check,
)
from .render.scad_io import SCAD_DIR
from .tables import read_bases, read_cells
from .temporal import (
    COMPLETION_TOL_MM,
    REFINE_DAMPING,
    REFINE_LOG,
    STAGE_FILE,
    closing_lengths,
    load_material,
    program_cells,
    program_design,
    time_limit,
    timing_errors,
)
from .temporal.membrane_model import MODEL_PATH as MEMBRANE_MODEL_PATH
from .temporal.membrane_model import load_membrane_model, validate_membrane_model_file

REPO_ROOT = Path(__file__).resolve().parent.parent
BUILD_ROOT = Path("build")


def _log(msg: str, progress: bool = True) -> None:
    if progress:
        print(f"[morphshell] {msg}", file=sys.stderr, flush=True)


def shape_name(source: str) -> str:
    """Folder name for a built-in shape name or a mesh path (its file stem).

    Raises
    ------
    InputError
        If ``source`` is neither a built-in shape (with valid options, e.g.
        ``dome:size=1.5``) nor an existing file.
    """
    source = str(source)
    p = Path(source)
    if p.is_file():
        return p.stem
    if p.is_dir():
        raise InputError(f"{source!r} is a directory, not a mesh file.",
                         fix="give the path of a mesh file (OBJ, STL, PLY, OFF) or a built-in "
                             "shape (morphshell shapes).")
    if "/" not in source and source in BUILTIN_SHAPES:
        check_spec(source)  # unknown options / non-numbers: fail before anything runs
        return source
    if p.suffix or "/" in source:
        raise InputError(f"mesh file {source!r} does not exist.",
                         fix="check the path, or use a built-in shape (morphshell shapes).")
    raise InputError(f"unknown shape {source!r}.",
                     fix="use one of the built-in shapes (" + ", ".join(BUILTIN_SHAPES)
                         + ") or give a mesh file path (OBJ, STL, PLY, OFF).")


def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def inputs_hash(source: str, options: dict) -> str:
    """Hash of everything a build depends on: the source, options, material file, code version."""
    h = hashlib.sha256()
    p = Path(source)
    h.update(_sha256_file(p).encode() if p.is_file() else source.encode())
    h.update(json.dumps(options, sort_keys=True, default=str).encode())
    if options.get("material"):
        h.update(_sha256_file(Path(options["material"])).encode())
    h.update(_version("morphshell").encode())
    return h.hexdigest()


def _version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def tool_versions() -> dict:
    """Versions of the project, OpenSCAD, Python and the key libraries."""
    v = {name: _version(name) for name in (
        "morphshell", "numpy", "scipy", "libigl", "trimesh", "manifold3d", "triangle",
        "pymeshlab", "scikit-sparse", "qpsolvers", "matplotlib", "pyvista",
        "openscad-evaluator")}
    v["python"] = sys.version.split()[0]
    try:
        out = subprocess.run(["openscad", "--version"], capture_output=True, text=True,
                             timeout=30)
        v["openscad"] = (out.stderr or out.stdout).strip().split("\n")[-1]
    except (OSError, subprocess.TimeoutExpired):
        v["openscad"] = "not found"
    return v


def design_only(source: str, *, out=None, progress: bool = True, **options) -> dict:
    """Run only the design stage into ``out`` (default ``build/<name>``), atomically."""
    check_design_options(**{k: v for k, v in options.items()
                            if k in ("vertices", "time", "scale", "flattening", "params",
                                     "size", "time_file")})
    name = shape_name(source)
    out = claim_output(out or BUILD_ROOT / name, what="output folder",
                       inputs=[source] + [options[k] for k in ("time_file", "thickness_file")
                                          if options.get(k)])
    with build_lock(out):
        recover_stale(out)
        with atomic_dir(out) as tmp:
            result = run_design(source, tmp, progress=progress, **options)
    _log(f"{name}: design -> {out}", progress)
    return result


def check_build_options(*, jobs=None, t_end=None, dt=None, refine=None, render: bool = True,
                        simulate: bool = True, renderer=None) -> None:
    """Refuse bad build options before any stage runs (even options of skipped stages:
    a typo should not wait for the next full build to show).

    Raises
    ------
    InputError
        Naming the option, its value and the rule; ``ExternalToolError`` when rendering is
        requested and OpenSCAD is missing.
    """
    if jobs is not None and (int(jobs) != jobs or not 1 <= jobs <= LIMITS.max_jobs):
        raise InputError(f"--jobs must be a whole number from 1 to {LIMITS.max_jobs}, got "
                         f"{jobs}.",
                         fix="omit --jobs (JOBS=) to use every CPU, or give e.g. --jobs 2.")
    if refine is not None and (int(refine) != refine or not 0 <= refine <= LIMITS.max_refine):
        raise InputError(f"--refine must be a whole number from 0 to {LIMITS.max_refine}, "
                         f"got {refine}.", fix=f"use e.g. --refine {DEFAULT_REFINE} (the "
                                               "default), or 0 for no refinement")
    for opt, v, lo, hi in (("--t-end", t_end, 0.0, LIMITS.max_t_end),
                           ("--dt", dt, LIMITS.min_dt, LIMITS.max_t_end)):
        if v is not None and not (math.isfinite(v) and v > 0 and lo <= v <= hi):
            raise InputError(f"{opt} must be a number of seconds from {lo:g} to {hi:g}, "
                             f"got {v}.",
                             fix=f"omit {opt} for the default, or give e.g. "
                                 f"{opt} {SIM.t_end if opt == '--t-end' else SIM.dt:g}.")
    steps = (t_end or SIM.t_end) / (dt or SIM.dt)
    if steps > LIMITS.max_steps:
        raise InputError(f"--t-end / --dt = {steps:.0f} simulation steps, more than "
                         f"{LIMITS.max_steps}.", fix="use a larger --dt or a shorter --t-end.")
    if simulate and (t_end is not None or dt is not None):
        kw = {k: float(v) for k, v in (("t_end", t_end), ("dt", dt)) if v is not None}
        SimSettings(**kw).times()  # t_end must be a multiple of dt
    if render:
        if check_renderer(renderer or DEFAULT_RENDERER) != "fast":
            find_openscad()  # missing OpenSCAD: say so now, not after the design stage


def build(source: str, *, out=None, vertices=None, time=None, scale: float = 1.0,
          flattening: str = "cetm", stencil_order: bool = False, material=None,
          refine: int = DEFAULT_REFINE, program: bool = True, render: bool = True,
          simulate: bool = True, t_end=None, dt=None, jobs=None,
          progress: bool = True, renderer=None, keep_failed: bool = False,
          solver: str = "fast", params=None, size=None, time_file=None,
          seed=None, stencil: bool = False) -> dict:
    """Build ``build/<name>/`` for a built-in shape or a mesh file.

    Parameters
    ----------
    source : str
        Built-in shape name (``petal``, ``saddle``, ``dome``, ``weave``, ``spiral``,
        ``regular``) or a path to a mesh / stencil OBJ.
    out : path-like, optional
        Output folder (default ``build/<name>``).
    vertices, time, time_file, scale, size, flattening, stencil_order, stencil
        Design options, see :func:`pysolver.design.run_design`.
    material : path-like, optional
        Bracket model file (default: the committed model).
    refine : int
        Rounds of timing correction from the simulation (temporal programming).
    program, render, simulate : bool
        Run the temporal programming, STL rendering, and simulation + report stages.
    t_end : float, s, optional
        Simulated time in water (default 120 s).
    dt : float, s, optional
        Simulation time step (default 0.5 s).
    jobs : int, optional
        Parallel OpenSCAD processes.
    renderer : {"openscad", "fast", "auto"}, optional
        Part renderer of the render stage (default
        :data:`pysolver.render.DEFAULT_RENDERER`), see :func:`pysolver.render.render_parts`.
    solver : {"fast", "reference"}
        Linear-algebra path of the simulations (:data:`~pysolver.mechanics.solver.SOLVERS`; same).
    params : UnitCell, optional
        Unit cell with the user's tolerances (:func:`pysolver.design.unit_cell_options`);
        default :data:`pysolver.params.UNIT_CELL`.  Later stages read it from ``design.json``.
    seed : int, optional
        CVT remeshing seed of the design stage (default: searched); with ``vertices`` it
        picks one of several stencils of the same size.
    keep_failed : bool
        Keep the staging folder of a build whose stage fails (``--debug``); by default it
        is removed, so a failed build leaves nothing behind.

    Returns
    -------
    summary : dict
        The content of ``summary.json`` plus ``exit_code``.
    """
    params = UNIT_CELL if params is None else params
    validate_model_files(material, unit=params)  # model files, before any stage
    check_design_options(vertices=vertices, time=time, scale=scale, flattening=flattening,
                         params=params, size=size, time_file=time_file)
    check_build_options(jobs=jobs, t_end=t_end, dt=dt, refine=refine, render=render,
                        simulate=simulate, renderer=renderer)
    name = shape_name(source)
    # absolute: stages may run external tools in other working directories (OpenSCAD)
    out = claim_output(out or BUILD_ROOT / name, what="output folder",
                       inputs=[source, material, time_file])
    design_opts = dict(vertices=vertices, time=time, scale=scale, flattening=flattening,
                       stencil_order=stencil_order, params=params)
    if seed is not None:  # (only when given: keeps the hash of earlier builds)
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**32:
            raise InputError(f"--seed must be a whole number from 0 to 2^32 - 1, got {seed!r}",
                             fix="give e.g. --seed 1")
        design_opts["seed"] = seed
    all_opts = dict(design_opts, material=str(material) if material else None, refine=refine,
                    program=program, t_end=t_end)
    all_opts.pop("params")
    if size is not None:  # (only when given, as dt and params)
        design_opts["size"] = all_opts["size"] = size
    if stencil:  # (only when given: keeps the hash of earlier builds)
        design_opts["stencil"] = all_opts["stencil"] = True
    if time_file is not None:  # the file's content is an input: its hash goes into the digest
        design_opts["time_file"] = all_opts["time_file"] = str(time_file)
        all_opts["time_file_sha256"] = read_time_file(time_file)[1]
    if params != UNIT_CELL:  # (only when changed: keeps the hash of earlier builds)
        all_opts["params"] = params.to_dict()
    if dt is not None:  # (only when given: keeps the hash of earlier builds)
        all_opts["dt"] = dt
    digest = inputs_hash(source, all_opts)
    staging = staging_dir(out)
    summary: dict = {"shape": name, "source": str(source), "options": all_opts,
                     "inputs_sha256": digest, "stages": {}, "timings_s": {},
                     "stage_inputs": {}}
    t_build = _now()
    with build_lock(out):
        recover_stale(out)
        _prepare_staging(staging, digest, progress)
        stages = summary["stages"]

        def stage(key: str, fn, *a, **kw):
            _log(f"{name}: {key} ...", progress)
            t0 = _now()
            try:
                res = fn(*a, **kw)
            except MorphshellError as e:  # say which stage, and what was (not) kept
                kept = (f"the previous complete build in {out} is unchanged"
                        if out.exists() else f"nothing was written to {out}")
                if keep_failed:
                    kept += f"; this build's partial files are in {staging}"
                else:
                    remove_staging(staging)
                    kept += ("; this build's partial files were removed (add --debug to "
                             "keep them)")
                problem, fix = e.problem, e.fix
                if not keep_failed:  # name files of the removed folder by their own names
                    problem, fix = (m and m.replace(f"{staging}/", "").replace(
                        str(staging), "the design folder") for m in (problem, fix))
                raise type(e)(f"{key} stage: {problem}\n  ({kept})", fix=fix) from e
            summary["timings_s"][key] = round(_now() - t0, 3)
            stages[key] = res if isinstance(res, dict) else {}
            _log(f"{name}: {key} done in {summary['timings_s'][key]:.1f} s", progress)
            return res

        if render:  # the renderer's self-check runs on the core the next stages leave idle
            start_self_check(staging, renderer=renderer)
        if simulate:  # so does the report's probe of off-screen rendering (a subprocess)
            start_pyvista_probe()
        stage("design", run_design, source, staging, progress=progress, **design_opts)
        if program:
            # A shape's own landscape gives the order of completion; its seconds are mapped
            # onto what the material can achieve.  A user's landscape is only checked.
            stage("program", program_design, staging, material=material, progress=progress,
                  fit_landscape=time is None and time_file is None)
        if simulate:
            kw = {} if t_end is None else {"t_end": t_end}
            sim_kw = dict(kw) if dt is None else dict(kw, dt=dt)
            stage("simulate", simulate_design, staging, material=material, progress=progress,
                  solver=solver, **sim_kw)
            physics = None

            def simulate_with_contact_if_needed(after: str):
                """Contact from here on when the frames just written collide."""
                nonlocal physics
                physics, hit = _contact_if_needed(staging, name, progress)
                if physics is not None:
                    stages[after]["contact"] = {"switched_on": True, "collisions": hit}
                    stage("simulate_contact", simulate_design, staging, material=material,
                          progress=progress, solver=solver, physics=physics, **sim_kw)

            simulate_with_contact_if_needed("simulate")
            if refine and program:
                hook = {"simulate": functools.partial(
                    simulate_design, solver=solver, **({} if dt is None else {"dt": dt}),
                    **({} if physics is None else {"physics": physics}))}
                stage("refine", refine_design, staging, iterations=refine, material=material,
                      progress=progress, **kw, **hook)
                if physics is None:  # the refined thicknesses may bring far parts together
                    simulate_with_contact_if_needed("refine")
        if render:  # after refinement, so the STLs carry the final thicknesses
            stage("render", render_design, staging, jobs=jobs, progress=progress,
                  renderer=renderer)
        if simulate:
            stage("report", make_report, staging, progress=progress,
                  build_info={k: summary[k] for k in ("source", "options", "inputs_sha256")})
        summary["stage_inputs"] = _stage_inputs(staging, material=material, t_end=t_end, dt=dt)
        summary["kept"] = _keep_skipped_outputs(out, staging, summary["stage_inputs"],
                                                render=render, simulate=simulate,
                                                progress=progress)
        summary["timings_s"]["total"] = round(_now() - t_build, 3)
        summary["versions"] = tool_versions()
        summary["figures"] = _key_figures(staging, stages)
        summary["output"] = str(out)
        atomic_write_text(staging / "summary.json",
                          json.dumps(summary, indent=2, sort_keys=True, default=_json_default)
                          + "\n")
        (staging / ".inputs_sha256").unlink(missing_ok=True)
        write_stamp(staging)
        public_mode(staging, recursive=True)
        replace_dir(staging, out)
        remove_staging(staging)
    _log(f"{name}: build complete in {summary['timings_s']['total']:.1f} s -> {out}", progress)
    if "report" in stages:
        print_verdict(stages["report"], out / "report")
    verdict = stages.get("report", {}).get("verdict")
    summary["exit_code"] = EXIT_CHECK_FAILED if verdict == "FAIL" else EXIT_OK
    return summary


# ----------------------------------------------------------------------------------------------
# closing the timing loop: temporal programming <-> simulation (the orchestrator's job)
# ----------------------------------------------------------------------------------------------


def _log_refine(msg: str, progress: bool) -> None:
    if progress:
        print(f"[temporal] {msg}", file=sys.stderr, flush=True)


def _thin_open_layers(cap, h_prev, t_sim, t_star, t_end, frames_path, tol_mm):
    """Caps on the thickness of the layers that stayed open in a cell that never completed
    although due.

    The time correction cannot close such a cell when it already asks for the cell's
    fastest time (a clamped cell, or a strongly folded one whose one layer must contract
    several times more than the other): the force balance behind the thicknesses
    (:func:`~pysolver.temporal.program.program_cells`) then over-estimates the membrane
    pull the simulation finds.  Each layer the last frame shows open
    (:func:`sim.model.collisions.open_layers`) is capped ``MODEL_LIMITS.refine_open_layer_mm``
    below its thickness in the round that left it open (not below
    ``UNIT_CELL.thickness_min``).  A capped layer never thickens again in later rounds
    (the caller lowers the cap to the thickness used), so that a cell the cap closed is
    not opened again by the next time correction.

    Parameters
    ----------
    cap : (n, 2) float, mm -- caps so far (``inf`` = none), (top, bottom)
    h_prev : (n, 2) float, mm -- thicknesses of the simulated round
    t_sim, t_star : (n,) float, s -- simulated completion (NaN = never) and targets
    t_end : float, s -- last simulated time
    frames_path : path -- that round's ``frames.npz``
    tol_mm : float, mm -- completion tolerance

    Returns
    -------
    cap : (n, 2) float, mm
    n_thinned : int -- layers newly capped below their previous thickness
    """
    h_prev = np.asarray(h_prev, float)
    thin = open_layers(frames_path, tol_mm) & never_due(t_sim, t_star, t_end)[:, None]
    h_min = UNIT_CELL.thickness_min
    lower = np.maximum(h_min, h_prev - MODEL_LIMITS.refine_open_layer_mm)
    cap = np.where(thin, np.minimum(cap, lower), cap)
    return cap, int((thin & (h_prev > h_min)).sum())


def _best_iteration(hist) -> int:
    """The refinement round to keep: fewest cells that never complete although due (the
    simulation check's count; clamped cells included), then the lowest
    ``rms_incl_never_s``."""
    def key(h):
        rms = h["rms_incl_never_s"]
        return (h["n_never_due"], rms if np.isfinite(rms) else np.inf)
    return min(range(len(hist)), key=lambda k: key(hist[k]))


def _refine_again(hist, k: int, rounds: int) -> bool:
    """Whether the refinement runs round ``k + 1``: the ``rounds`` asked for, then up to
    ``MODEL_LIMITS.refine_extra_rounds`` more while the best round so far leaves cells that
    never complete, and the last round either thinned a layer or closed a cell (otherwise
    another simulation could not change anything the time correction has not)."""
    if k < rounds:
        return True
    if rounds == 0 or k >= rounds + MODEL_LIMITS.refine_extra_rounds:
        return False
    last, before = hist[-1], hist[-2]
    moved = last["n_layers_thinned"] > 0 or last["n_never_due"] < before["n_never_due"]
    return moved and hist[_best_iteration(hist)]["n_never_due"] > 0


def _round_record(t_star, t_sim, clamped, t_end, **extra) -> dict:
    """One refinement round's figures: :func:`timing_errors` and the cells that never
    complete although due (:func:`sim.model.collisions.never_due`)."""
    stuck = never_due(t_sim, t_star, t_end)
    return dict(timing_errors(t_star, t_sim, clamped, t_end), n_never_due=int(stuck.sum()),
                never_due_cells=[int(i) for i in np.flatnonzero(stuck)[:REPORT.listed_cells]],
                **extra)


def refine_design(design_dir, *, iterations: int = 1, material=None, membrane=None,
                  progress: bool = True, t_end=None, damping: float = REFINE_DAMPING,
                  tol_mm: float = COMPLETION_TOL_MM, simulate=None, physics=None) -> dict:
    """Correct the programmed times from simulated completion times and re-simulate.

    Needs a programmed and simulated design folder (``sim/frames.npz``).  Each
    iteration moves the requested time of every cell by ``damping * (t* - t_sim)``
    (cells that never complete count as ``t_end``), clamps it to the cell's
    achievable range, re-solves the thicknesses (``t_star_s`` stays the user's
    target), and re-simulates.  A cell that never completes also has the layers it left
    open thinned (:func:`_thin_open_layers`).  When the ``iterations`` rounds leave cells
    that never complete, up to ``MODEL_LIMITS.refine_extra_rounds`` more rounds run while
    they do.  The round with the fewest cells that never complete, then the lowest RMS
    timing error (clamped cells excluded, cells that never complete counted as finishing
    at the last frame) is kept: its thicknesses in ``cells.csv`` and its frames in
    ``sim/frames.npz``.

    Parameters
    ----------
    design_dir : path-like
    iterations : int
        Number of correct + re-simulate rounds K (0 = none, and no extra rounds).
    material, membrane : optional
        As :func:`program_design`; ``material`` is also passed to the simulator.
    t_end : float, s, optional
        Simulated time (default: the simulator's default).
    damping : float
        Fraction of the timing error corrected per round (0 < damping <= 1).
    tol_mm : float, mm
        Completion tolerance (:func:`simulated_completion`).
    simulate : callable, optional
        ``simulate(design_dir, **kw)`` replacing :func:`sim.model.simulate.simulate_design`
        (tests).
    physics : PhysicsOptions, optional
        The simulator's physics (default :data:`~pysolver.params.PHYSICS_DEFAULT`): the
        layers are programmed to close where it closes them
        (:func:`pysolver.temporal.program.closing_lengths`).

    Returns
    -------
    dict
        ``iterations`` (asked), ``rounds`` (run), ``damping``, ``history`` (per round:
        :func:`timing_errors`, ``n_never_due`` and ``never_due_cells``, the thickness range,
        ``n_layers_thinned``: layers newly capped, and the seconds taken), ``best`` (round
        index, 0 = before refinement: the fewest cells that never complete although due,
        then the lowest ``rms_incl_never_s``), ``before``/``after`` (round 0 and the best
        one) and a ``note``.
    """
    design_dir = Path(design_dir)
    if int(iterations) != iterations or iterations < 0:
        raise InputError(f"iterations must be a non-negative integer, got {iterations!r}.")
    if not 0 < damping <= 1:
        raise InputError(f"damping must be in (0, 1], got {damping!r}.")
    frames_path = design_dir / "sim" / "frames.npz"
    if not frames_path.is_file():
        raise InputError(f"{frames_path} does not exist: refine needs a simulated design.",
                         fix="run the simulate stage first (morphshell simulate DIR).")
    if simulate is None:
        simulate = simulate_design
    sim_kw = {"progress": progress}
    if material is not None:
        sim_kw["material"] = material
    if t_end is not None:
        sim_kw["t_end"] = t_end
    mat = load_material(material)
    mem = load_membrane_model(membrane)

    cells = tables.read_table(design_dir, "cells")
    closing = closing_lengths(design_dir, cells, physics)
    t_star = cells["t_star_s"].copy()
    factor = None
    rec = design_dir / STAGE_FILE
    if rec.is_file():
        f = json.loads(rec.read_text()).get("membrane_factor")
        if f is not None and len(f) == len(t_star):
            factor = np.asarray(f, float)
    clamped = cells["clamped"].astype(bool)
    t_lo, t_hi = cells["t_min_s"], cells["t_max_s"]
    t_sim, t_frames = simulated_completion(design_dir, tol_mm)
    t_last = float(t_frames[-1]) if len(t_frames) else float(SIM.t_end)
    keep_dir = design_dir / "sim" / "refine"
    keep_dir.mkdir(parents=True, exist_ok=True)
    shutil.copy2(frames_path, keep_dir / "frames_0.npz")
    th0 = np.column_stack([cells["thickness_top_mm"], cells["thickness_bottom_mm"]])
    hist = [_round_record(t_star, t_sim, clamped, t_last, iteration=0,
                          thickness_mm=[float(th0.min()), float(th0.max())])]
    thick = [th0]
    cap = np.full(th0.shape, np.inf)
    _log_refine(f"{design_dir.name}: before refinement rms {hist[0]['rms_s']:.2f} s, spearman "
         f"{hist[0]['spearman']:.3f}, {hist[0]['n_never_due']} never complete", progress)
    lo_ok = np.where(np.isfinite(t_lo), t_lo, 0.0)
    hi_ok = np.where(np.isfinite(t_hi), t_hi, time_limit(mat))
    t_req = np.clip(t_star, lo_ok, np.maximum(lo_ok, hi_ok))
    rounds, k = int(iterations), 0
    while _refine_again(hist, k, rounds):
        k += 1
        t0 = time.perf_counter()
        ts = np.where(np.isfinite(t_sim), t_sim, t_last)
        t_req = np.clip(t_req + damping * (t_star - ts), lo_ok, np.maximum(lo_ok, hi_ok))
        res = program_cells(cells["bracket_length_mm"], closing[:, 0], closing[:, 1],
                            cells["boundary"], t_star,
                            material=mat, membrane=mem, t_request=t_req, factor=factor)
        cap, n_thinned = _thin_open_layers(cap, thick[-1], t_sim, t_star, t_last, frames_path,
                                           tol_mm)
        th = np.minimum(res["thickness"], cap)
        cap = np.where(np.isfinite(cap), th, cap)  # a capped layer never thickens again
        out = dict(cells)
        out["thickness_top_mm"] = th[:, 0]
        out["thickness_bottom_mm"] = th[:, 1]
        tables.write_table(design_dir / tables.FILENAMES["cells"], "cells", out)
        simulate(design_dir, **sim_kw)
        t_sim, t_frames = simulated_completion(design_dir, tol_mm)
        shutil.copy2(frames_path, keep_dir / f"frames_{k}.npz")
        thick.append(th)
        hist.append(_round_record(t_star, t_sim, clamped, t_last, iteration=k,
                                  thickness_mm=[float(th.min()), float(th.max())],
                                  n_layers_thinned=n_thinned,
                                  seconds=round(time.perf_counter() - t0, 1)))
        _log_refine(f"{design_dir.name}: refine {k}/{max(k, rounds)}: rms "
                    f"{hist[-1]['rms_s']:.2f} s, "
             f"spearman {hist[-1]['spearman']:.3f}, {hist[-1]['n_never_due']} never complete "
             f"({hist[-1]['seconds']:.0f} s)", progress)
    best = _best_iteration(hist)
    if best != len(hist) - 1:
        out = dict(cells)
        out["thickness_top_mm"] = thick[best][:, 0]
        out["thickness_bottom_mm"] = thick[best][:, 1]
        tables.write_table(design_dir / tables.FILENAMES["cells"], "cells", out)
        shutil.copy2(keep_dir / f"frames_{best}.npz", frames_path)
    for f in keep_dir.glob("frames_*.npz"):
        f.unlink()
    keep_dir.rmdir()
    result = {"iterations": int(iterations), "rounds": k, "damping": damping, "history": hist,
              "best": best, "before": hist[0], "after": hist[best],
              "note": "rms_s: cells whose t* is achievable (clamped excluded) and that "
                      "complete; rms_incl_never_s also counts cells that never complete as "
                      "finishing at the last simulated time; n_never_due: cells due by the "
                      "last simulated time that never complete, clamped ones included. The "
                      "best round has the fewest n_never_due, then the lowest "
                      "rms_incl_never_s: a round that closes more cells is kept even at a "
                      "larger timing error."}
    atomic_write_text(design_dir / "sim" / REFINE_LOG, json.dumps(result, indent=1) + "\n")
    return result


def validate_model_files(material=None, membrane=None, unit=UNIT_CELL) -> None:
    """Check every model file a build will read, before any stage runs; the material model
    must be fitted for the unit cell's brackets (:func:`check_bracket_geometry`).

    Parameters
    ----------
    material : path-like or bracket model object, optional
        ``--material FILE``; None checks the committed bracket model; an object (already a
        model) is not a file and is skipped.
    membrane : path-like, optional
        Membrane model file (default: the committed one).
    unit : UnitCell
        The unit cell of the build.

    Raises
    ------
    InputError
        The first rule a file breaks.
    """
    if material is None or isinstance(material, str | os.PathLike):
        path = DEFAULT_MODEL_PATH if material is None else material
        check_bracket_geometry(load_bracket_model(path), unit, str(path))  # (validates it)
    if membrane is None or isinstance(membrane, str | os.PathLike):
        validate_membrane_model_file(MEMBRANE_MODEL_PATH if membrane is None else membrane)
def _contact_if_needed(folder: Path, name: str, progress: bool):
    """Physics options with barrier contact when the simulation of ``folder`` lets
    non-neighbouring bases pass through each other.

    The reference model has no contact between far-apart parts; when they meet on the way
    (a petal sweeping past another), its path is impossible and the check could only say
    FAIL.  The printed shell's parts push each other aside instead, which the IPC barrier
    (``--physics contact``, :mod:`sim.model.contact`) models, so the build simulates again with it.
    A shell whose parts never meet keeps the reference model's result unchanged.

    Returns
    -------
    physics : PhysicsOptions or None
        ``contact`` switched on; None when no pair collides.
    hit : dict
        :meth:`sim.model.collisions.CollisionResult.summary` of the frames checked.
    """
    hit = base_base_collisions(folder)
    if not hit["count"]:
        return None, hit
    f = hit["first"]
    _log(f"{name}: {hit['count']} pair(s) of non-neighbouring bases pass through each other "
         f"(first bases {f['pair'][0]} and {f['pair'][1]} at t = {f['time_s']:g} s); "
         "simulating again with barrier contact (--physics contact)", progress)
    return parse_physics("default,contact"), hit


# ------------------------------------------------------------------------------------------
# The simulator and its check for the other front ends.  The tolerance analysis and the
# studio ask the orchestrator, the one module that composes the stages, rather than import
# the simulator or its report (data flows forward: docs/for-contributors.md).


def check_sim_span(t_end: float, dt: float) -> None:
    """Refuse a simulated span that the simulator would refuse, before any work is spent.

    Parameters
    ----------
    t_end : float, s
        End of the simulated time.
    dt : float, s
        Time step; ``t_end`` must be a whole number of steps.

    Raises
    ------
    InputError
        Naming the value and the rule.
    """
    SimSettings(t_end=float(t_end), dt=float(dt)).times()


def simulate_and_check(model, material, ctx: dict, *, t_end: float, dt: float,
                       thresholds=None):
    """Simulate a shell model in memory and check it as the report does.

    Parameters
    ----------
    model : pysolver.mechanics.ShellModel
        The shell (e.g. a perturbed copy from :func:`pysolver.mechanics.vary_model`).
    material : BracketModel
        Anything with the bracket model's ``coefficients``.
    ctx : dict
        The design's arrays for the check (:func:`sim.report.check_frames`).
    t_end, dt : float, s
        Simulated span and time step.
    thresholds : Thresholds or dict, optional
        Verdict limits (default: the report's).

    Returns
    -------
    frames : dict
        As :func:`sim.model.simulate.simulate_model` returns them.
    check : dict or None
        :func:`sim.report.check_frames` of the frames; None with fewer than two frames.

    Raises
    ------
    MorphshellError
        When the simulation diverges (raised by the simulator, before any check).
    """
    frames = simulate_model(model, material, t_end=t_end, dt=dt)
    if len(frames["t"]) < 2:
        return frames, None
    return frames, check_frames(frames, ctx, thresholds)


def viewer_assets() -> dict:
    """The 3D morph viewer's static files, ``{name: path}`` (the studio serves them)."""
    return {name: VIEWER_DIR / name for name in VIEWER_ASSETS}


def morph_viewer(folder, *, max_frames: int, quantise: bool) -> dict:
    """The 3D viewer's data of a simulated design folder (:func:`sim.viewer.viewer_data`).

    Parameters
    ----------
    folder : path-like
        Design folder with ``sim/frames.npz``.
    max_frames : int
        Frames kept (evenly spaced, the end kept).
    quantise : bool
        Positions as uint16 over their box (smaller) rather than float32.

    Returns
    -------
    dict
        The JSON the viewer reads.
    """
    sd = load_sim(folder)
    fr = sd.frames
    t_done, _ = completion_times(fr["t"], fr["collided"], fr.get("bracket_length"),
                                 fr.get("collision_length"))
    return viewer_data(sd, t_done, max_frames=max_frames, quantise=quantise)


def _now() -> float:
    return time.perf_counter()


def _prepare_staging(staging: Path, digest: str, progress: bool) -> None:
    """Reuse the staging folder of an interrupted build with the same inputs, else start clean."""
    marker = staging / ".inputs_sha256"
    if staging.exists():
        if marker.exists() and marker.read_text().strip() == digest:
            _log(f"resuming the interrupted build in {staging}", progress)
            return
        remove_staging(staging)
    staging.mkdir(parents=True)
    marker.write_text(digest + "\n")


# outputs of the stages a build may skip, and what they are computed from
_SKIPPABLE = {"render": ("scad", "stl"), "simulate": ("sim", "report")}


def _stage_inputs(folder: Path, *, material=None, t_end=None, dt=None) -> dict:
    """Hash of what the render and the simulation (+ report) stages read: the design tables
    and stencil, plus the SCAD library (render) or the material model and time settings
    (simulate).  Equal hashes mean a skipped stage's earlier outputs are still right."""
    h = hashlib.sha256()
    for f in sorted(folder.glob("*.csv")) + [folder / "stencil.obj"]:
        h.update(f.name.encode() + b"\0" + (f.read_bytes() if f.is_file() else b"") + b"\0")
    tables = h.hexdigest()
    lib = hashlib.sha256(b"".join(p.name.encode() + p.read_bytes()
                                  for p in sorted(Path(SCAD_DIR).glob("*.scad"))))
    mat = _sha256_file(Path(material)) if material else "committed:" + _version("morphshell")
    sim = json.dumps({"material": mat, "t_end": t_end, "dt": dt}, sort_keys=True)
    return {"render": hashlib.sha256((tables + lib.hexdigest()).encode()).hexdigest(),
            "simulate": hashlib.sha256((tables + sim).encode()).hexdigest()}


def _keep_skipped_outputs(out: Path, staging: Path, current: dict, *, render: bool,
                          simulate: bool, progress: bool) -> dict:
    """Carry the previous build's outputs of a skipped stage into ``staging`` when what they
    were computed from is unchanged; otherwise say that they are dropped.

    Returns
    -------
    dict
        ``{stage: "kept" | "dropped"}`` for every skipped stage the previous build had run.
    """
    try:
        old = json.loads((out / "summary.json").read_text()).get("stage_inputs", {})
    except (OSError, ValueError, AttributeError):
        old = {}
    result = {}
    for stage, folders in _SKIPPABLE.items():
        if (render if stage == "render" else simulate):
            continue
        present = [f for f in folders if (out / f).is_dir()]
        if not present:
            continue
        if old.get(stage) == current[stage]:
            for f in present:
                shutil.copytree(out / f, staging / f, copy_function=_link_or_copy)
            result[stage] = "kept"
            _log(f"{stage} not run: kept the previous {', '.join(present)} (inputs unchanged)",
                 progress)
        else:
            result[stage] = "dropped"
            _log(f"{stage} not run: the previous {', '.join(p + '/' for p in present)} no "
                 "longer match the design and are dropped; re-run without "
                 f"--no-{'render' if stage == 'render' else 'sim'} to make them again",
                 progress)
    return result


def _link_or_copy(src, dst):
    """Hard-link a file (instant, no extra space), copying it where links are impossible."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _key_figures(folder: Path, stages: dict) -> dict:
    """A few headline numbers collected from the stage results and the tables."""
    fig: dict = {}
    try:
        bases = read_bases(folder / "bases.csv")
        cells = read_cells(folder / "cells.csv")
        fig["n_bases"] = len(bases["base_id"])
        fig["n_cells"] = len(cells["cell_id"])
        for key in ("thickness_top_mm", "thickness_bottom_mm"):
            if key in cells:
                fig[f"{key}_range"] = [float(cells[key].min()), float(cells[key].max())]
        fig["max_central_length_mm"] = float(cells["central_length_mm"].max())
    except Exception as e:  # figures are a summary, never a reason to fail a build
        fig["error"] = f"{type(e).__name__}: {e}"
    rep = stages.get("report", {})
    if rep:
        fig["verdict"] = rep.get("verdict")
    return fig


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(type(o).__name__)
