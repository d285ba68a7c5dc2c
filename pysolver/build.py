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
import tomllib
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
from sim.report.fabrication import parts_made_from, stl_inventory
from sim.report.plots import start_pyvista_probe
from sim.viewer import ASSETS as VIEWER_ASSETS
from sim.viewer import STATIC_DIR as VIEWER_DIR
from sim.viewer import viewer_data

from . import tables
from .atomic import (
    STAMP_NAME,
    atomic_dir,
    atomic_write_text,
    build_lock,
    claim_output,
    open_staging,
    public_mode,
    recover_stale,
    remove_staging,
    replace_dir,
    seal,
    staging_dir,
)
from .design import check_design_options, run_design
from .design.surfaces import BUILTIN_SHAPES, check_spec
from .design.time_landscape import read_time_file, write_landscape
from .errors import EXIT_CHECK_FAILED, EXIT_OK, InputError, MorphshellError, check_input_file
from .material.model import check_bracket_geometry, load_bracket_model
from .params import (
    BRACKET_MODEL_FILE,
    DEFAULT_REFINE,
    LIMITS,
    MEMBRANE_MODEL_FILE,
    PROGRAMMING,
    REPORT,
    SIM,
    UNIT_CELL,
)
from .render import (
    DEFAULT_RENDERER,
    check_renderer,
    find_openscad,
    render_design,
    start_self_check,
)
from .render.scad_io import SCAD_DIR
from .tables import read_bases, read_cells, read_record
from .temporal import (
    REFINE_LOG,
    STAGE_FILE,
    load_material,
    program_cells,
    program_design,
    time_limit,
    timing_errors,
)
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
    if p.exists() and not p.is_dir():
        check_input_file(p, "mesh file")  # a FIFO or a device: named, never read
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


LOCK_FILE = Path(__file__).resolve().parents[1] / "uv.lock"
"""The lock file that ``make`` installs (absent when morphshell is installed some other way)."""


def lock_record(lock=LOCK_FILE) -> dict:
    """The lock file's hash, and the installed packages whose version it does not pin.

    Returns
    -------
    dict
        ``sha256`` of ``uv.lock`` (None when there is none), ``mismatched``: sorted
        ``"name installed (lock: v1, v2)"`` for every package the lock pins that is installed
        at another version (empty when the environment is exactly the lock's).
    """
    lock = Path(lock)
    if not lock.is_file():
        return {"sha256": None, "mismatched": []}
    data = tomllib.loads(lock.read_text(encoding="utf-8"))
    pinned: dict = {}
    for pkg in data.get("package", []):
        if "version" in pkg and (pkg.get("source") or {}).get("editable") is None:
            pinned.setdefault(pkg["name"], set()).add(pkg["version"])
    bad = []
    for name, vers in sorted(pinned.items()):
        have = _version(name)
        if have != "not installed" and have not in vers:
            bad.append(f"{name} {have} (lock: {', '.join(sorted(vers))})")
    return {"sha256": _sha256_file(lock), "mismatched": bad}


def tool_versions() -> dict:
    """Versions of the project, OpenSCAD, Python and the key libraries, and the lock file's
    hash (:func:`lock_record`: ``lock_sha256``, ``lock_mismatched``)."""
    v = {name: _version(name) for name in (
        "morphshell", "numpy", "scipy", "libigl", "trimesh", "manifold3d", "triangle",
        "pymeshlab", "scikit-sparse", "qpsolvers", "matplotlib", "pyvista",
        "openscad-evaluator", "autograd", "numba")}
    v["python"] = sys.version.split()[0]
    lock = lock_record()
    v["lock_sha256"] = lock["sha256"]
    v["lock_mismatched"] = lock["mismatched"]
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
                       inputs=[source] + ([options["time_file"]] if options.get("time_file")
                                          else []))
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
          flattening: str = "cetm", stencil: bool = False, material=None,
          refine: int = DEFAULT_REFINE, program: bool = True, render: bool = True,
          simulate: bool = True, t_end=None, dt=None, jobs=None,
          progress: bool = True, renderer=None, keep_failed: bool = False,
          solver: str = "fast", params=None, size=None, time_file=None,
          seed=None) -> dict:
    """Build ``build/<name>/`` for a built-in shape or a mesh file.

    Parameters
    ----------
    source : str
        Built-in shape name (``petal``, ``saddle``, ``dome``, ``weave``, ``spiral``,
        ``regular``) or a path to a mesh / stencil OBJ.
    out : path-like, optional
        Output folder (default ``build/<name>``).
    vertices, time, time_file, scale, size, flattening, stencil
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
                       stencil=stencil, params=params)
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
                     "stage_inputs": {},
                     "run": {"render": bool(render), "renderer": renderer, "solver": solver}}
    t_build = _now()
    with build_lock(out):
        recover_stale(out)
        _prepare_staging(staging, digest, progress)
        stage = _stage_runner(summary, name, out, staging, keep_failed, progress)
        _start_checks(staging, render=render, simulate=simulate, renderer=renderer)
        stage("design", run_design, source, staging, progress=progress, **design_opts)
        # A shape's own landscape gives the order of completion; its seconds are mapped onto
        # what the material can achieve.  A user's landscape is only checked.
        _later_stages(stage, staging, name, summary, program=program, simulate=simulate,
                      render=render, refine=refine, material=material, t_end=t_end, dt=dt,
                      solver=solver, renderer=renderer, jobs=jobs,
                      fit_landscape=time is None and time_file is None, progress=progress)
        _finish(summary, staging, out, t_build, material=material, t_end=t_end, dt=dt,
                render=render, simulate=simulate, progress=progress)
    return _closing(summary, name, out, progress)


def _stage_runner(summary: dict, name: str, out: Path, staging: Path, keep_failed: bool,
                  progress: bool):
    """``stage(key, fn, *a, **kw)``: run one stage into ``summary`` (result, seconds), and on
    a :class:`MorphshellError` remove the staging folder (unless ``keep_failed``) and raise
    it again naming the stage and what was (not) kept."""
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

    return stage


def _start_checks(staging: Path, *, render: bool, simulate: bool, renderer) -> None:
    """Start the renderer's self-check and the report's off-screen rendering probe: they run
    on the core the first stages leave idle."""
    if render:
        start_self_check(staging, renderer=renderer)
    if simulate:  # a subprocess
        start_pyvista_probe()


def _later_stages(stage, staging: Path, name: str, summary: dict, *, program: bool,
                  simulate: bool, render: bool, refine: int, material, t_end, dt, solver,
                  renderer, jobs, fit_landscape: bool, progress: bool) -> None:
    """The stages after the design stage, into ``staging``: program -> simulate [-> contact]
    [-> refine] -> render -> report (:func:`build` and :func:`rebuild` run the same ones)."""
    stages = summary["stages"]
    if program:
        stage("program", program_design, staging, material=material, progress=progress,
              fit_landscape=fit_landscape)
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


def _finish(summary: dict, staging: Path, out: Path, t_build: float, *, material, t_end, dt,
            render: bool, simulate: bool, progress: bool) -> None:
    """Write ``summary.json`` into the finished staging folder, stamp it and move it to
    ``out`` (replacing the previous build)."""
    summary["stage_inputs"] = _stage_inputs(staging, material=material, t_end=t_end, dt=dt)
    summary["kept"] = _keep_skipped_outputs(out, staging, summary["stage_inputs"],
                                            render=render, simulate=simulate,
                                            progress=progress)
    summary["timings_s"]["total"] = round(_now() - t_build, 3)
    summary["versions"] = tool_versions()
    summary["figures"] = _key_figures(staging, summary["stages"])
    summary["output"] = str(out)
    atomic_write_text(staging / "summary.json",
                      json.dumps(summary, indent=2, sort_keys=True, default=_json_default)
                      + "\n")
    seal(staging)
    public_mode(staging, recursive=True)
    replace_dir(staging, out)
    remove_staging(staging)


def _closing(summary: dict, name: str, out: Path, progress: bool) -> dict:
    """Say that the build is complete, print the verdict and set ``exit_code``."""
    stages = summary["stages"]
    _log(f"{name}: build complete in {summary['timings_s']['total']:.1f} s -> {out}", progress)
    if "report" in stages:
        print_verdict(stages["report"], out / "report")
    verdict = stages.get("report", {}).get("verdict")
    summary["exit_code"] = EXIT_CHECK_FAILED if verdict == "FAIL" else EXIT_OK
    return summary


# ------------------------------------------------------------------------------------------
# a build again from an edited time landscape (the studio's "Run")

REBUILD_DROPPED = ("summary.json", "temporal.json", "temporal_feasibility.png", STAMP_NAME)
"""Top-level files of a build that a rebuild does not carry over (the later stages write
them again); its subfolders (``sim/``, ``report/``, ``scad/``, ``stl/``, ``tolerance/``) are
all made from the old tables and are not carried over either."""


def rebuild(folder, landscape, *, source: dict | None = None, progress: bool = True) -> dict:
    """Build a design folder again from a new time landscape, through the same stages as
    :func:`build` after the design stage, with the options that build recorded
    (``summary.json``): program (the landscape is the user's: checked, never rescaled),
    simulate (+ contact when parts pass through each other), refine (the build's
    ``--refine``), render (when the build rendered), report.

    The stages run in the staging folder, on a copy of the design stage's files with the new
    ``time_landscape.csv``; the folder is replaced only when all have finished.  A failed
    stage leaves the folder as it was (nothing of the edit is saved) and raises.

    Parameters
    ----------
    folder : path-like
        A folder made by ``morphshell build`` (with ``summary.json``).
    landscape : (n_vertices,) float, s
        Requested completion time per stencil vertex.
    source : dict, optional
        How the landscape was made, written as ``studio_landscape.json`` (the report's
        provenance); JSON-serialisable.
    progress : bool
        Progress lines on stderr (``[morphshell] <name>: <stage> ...``, as a build).

    Returns
    -------
    summary : dict
        The new ``summary.json`` plus ``exit_code`` (3 when the report's verdict is FAIL).

    Raises
    ------
    InputError
        Not a build folder, a landscape of the wrong length or with times outside
        ``[0, LIMITS.max_landscape_s]``, files morphshell did not write in the folder, or a
        stage refusing the landscape (the folder is then unchanged).
    """
    folder = Path(folder).absolute()
    old = read_record(folder / "summary.json")
    if not isinstance(old, dict) or not isinstance(old.get("options"), dict):
        raise InputError(f"{folder / 'summary.json'} is missing or unreadable: only a folder "
                         "made by 'morphshell build' can be built again from a landscape",
                         fix=f"build it first: morphshell build <shape> --out {folder}")
    opts, run = old["options"], old.get("run") or {}
    if not opts.get("program", True):
        raise InputError(f"{folder} was built without temporal programming (--no-program): a "
                         "landscape has nothing to program", fix="build it with programming")
    V, _, _ = tables.read_stencil(folder / "stencil.obj")
    land = tables.round_sig9(check_landscape(landscape, len(V)))   # as time_landscape.csv keeps it
    claim_output(folder, what="build folder")
    name = folder.name
    material, refine = opts.get("material"), int(opts.get("refine") or 0)
    t_end, dt = opts.get("t_end"), opts.get("dt")
    render = bool(run.get("render", (folder / "stl").is_dir()))
    renderer = run.get("renderer") or old.get("stages", {}).get("render", {}).get("renderer")
    solver = run.get("solver") or "fast"
    validate_model_files(material, unit=tables.read_unit_cell(folder))
    land_sha = hashlib.sha256(land.astype("<f8").tobytes()).hexdigest()
    edit = {"made_by": "morphshell studio", "edited_from_tables_sha256":
            tables.tables_sha256(folder), **(source or {})}
    digest = hashlib.sha256(f"{old.get('inputs_sha256')}\0{land_sha}".encode()).hexdigest()
    summary: dict = {"shape": old.get("shape", name), "source": old.get("source"),
                     "options": opts, "inputs_sha256": digest,
                     "stages": {k: v for k, v in old.get("stages", {}).items() if k == "design"},
                     "timings_s": {k: v for k, v in old.get("timings_s", {}).items()
                                   if k == "design"},
                     "stage_inputs": {}, "run": {"render": render, "renderer": renderer,
                                                 "solver": solver},
                     "edited": {"by": "morphshell studio", "landscape_sha256": land_sha,
                                "from_inputs_sha256": old.get("inputs_sha256"),
                                "before": report_figures(folder)}}
    t_build = _now()
    staging = staging_dir(folder)
    with build_lock(folder):
        recover_stale(folder)
        _prepare_staging(staging, digest, progress)
        for p in folder.iterdir():
            if p.is_file() and not p.is_symlink() and p.name not in REBUILD_DROPPED:
                shutil.copy2(p, staging / p.name)
        write_landscape(staging, land)
        atomic_write_text(staging / tables.LANDSCAPE_SOURCE, json.dumps(edit, indent=1) + "\n")
        stage = _stage_runner(summary, name, folder, staging, False, progress)
        _start_checks(staging, render=render, simulate=True, renderer=renderer)
        _later_stages(stage, staging, name, summary, program=True, simulate=True,
                      render=render, refine=refine, material=material, t_end=t_end, dt=dt,
                      solver=solver, renderer=renderer, jobs=None, fit_landscape=False,
                      progress=progress)
        _finish(summary, staging, folder, t_build, material=material, t_end=t_end, dt=dt,
                render=render, simulate=True, progress=progress)
    return _closing(summary, name, folder, progress)


def report_figures(folder) -> dict | None:
    """The headline figures of a build's report (``report/report.json``), None without one.

    Returns
    -------
    dict or None
        ``verdict``, ``reasons`` (list of ``{level, check, message}``), ``timing_rms_s``,
        ``spearman``, ``n_clamped``, ``n_never_complete`` (due by the end and never
        complete), ``n_cells``, ``shape_rms_mm``, ``shape_rms_pct``, ``refine_rounds``,
        ``parts_fresh`` (the STLs match the tables; None without STLs) and ``tables_sha256``.
    """
    r = read_record(Path(folder) / "report" / "report.json")
    if not isinstance(r, dict) or not isinstance(r.get("metrics"), dict):
        return None
    m = r["metrics"]
    tm, sh = m.get("timing") or {}, m.get("shape") or {}
    tb = m.get("tables") or {}
    parts = tb.get("parts") or {}
    return {"verdict": r.get("verdict"), "reasons": r.get("reasons") or [],
            "timing_rms_s": tm.get("rms_s"), "spearman": tm.get("spearman"),
            "n_clamped": tm.get("n_clamped"), "n_never_complete": tm.get("n_never_due"),
            "n_cells": tm.get("n_cells"), "shape_rms_mm": sh.get("rms_mm"),
            "shape_rms_pct": sh.get("rms_pct"),
            "refine_rounds": (r.get("provenance") or {}).get("refine_rounds"),
            "parts_fresh": parts.get("fresh") if parts.get("n_stl") else None,
            "tables_sha256": tb.get("sha256")}


def build_parts(folder) -> dict:
    """The printable parts of a build: whether they match its tables
    (:func:`sim.report.fabrication.parts_made_from`) and, when they do, the STL list
    (:func:`sim.report.fabrication.stl_inventory`: name, bytes, triangles, size, purpose).

    Returns
    -------
    dict
        ``made_from`` and ``stls`` (empty when the STLs are stale or absent).
    """
    made = parts_made_from(folder)
    return {"made_from": made, "stls": stl_inventory(folder, made)}


def check_landscape(landscape, n_vertices: int) -> np.ndarray:
    """A time landscape from outside (the studio): ``n_vertices`` finite times in
    ``[0, LIMITS.max_landscape_s]`` s.

    Raises
    ------
    InputError
        Naming the first bad value and the rule.
    """
    try:
        land = np.asarray(landscape, dtype=float)
    except (TypeError, ValueError):
        raise InputError("the landscape is not a list of numbers",
                         fix="give one time in seconds per stencil vertex") from None
    if land.shape != (n_vertices,):
        raise InputError(f"the landscape has {land.size} values, the stencil {n_vertices} "
                         "vertices", fix="give one time in seconds per stencil vertex")
    bad = np.flatnonzero(~np.isfinite(land) | (land < 0) | (land > LIMITS.max_landscape_s))
    if bad.size:
        raise InputError(f"vertex {bad[0]}: time {float(land[bad[0]])!r} s is outside 0-"
                         f"{LIMITS.max_landscape_s:g} s ({bad.size} such vertices)",
                         fix=f"give times from 0 to {LIMITS.max_landscape_s:g} s")
    return land


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
    (:func:`sim.model.collisions.open_layers`) is capped ``PROGRAMMING.refine_open_layer_mm``
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
    lower = np.maximum(h_min, h_prev - PROGRAMMING.refine_open_layer_mm)
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
    ``PROGRAMMING.refine_extra_rounds`` more while the best round so far leaves cells that
    never complete, and the last round either thinned a layer or closed a cell (otherwise
    another simulation could not change anything the time correction has not)."""
    if k < rounds:
        return True
    if rounds == 0 or k >= rounds + PROGRAMMING.refine_extra_rounds:
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
                  progress: bool = True, t_end=None, damping: float = PROGRAMMING.refine_damping,
                  tol_mm: float = UNIT_CELL.clearance, simulate=None) -> dict:
    """Correct the programmed times from simulated completion times and re-simulate.

    Needs a programmed and simulated design folder (``sim/frames.npz``).  Each
    iteration moves the requested time of every cell by ``damping * (t* - t_sim)``
    (cells that never complete count as ``t_end``), clamps it to the cell's
    achievable range, re-solves the thicknesses (``t_star_s`` stays the user's
    target), and re-simulates.  A cell that never completes also has the layers it left
    open thinned (:func:`_thin_open_layers`).  When the ``iterations`` rounds leave cells
    that never complete, up to ``PROGRAMMING.refine_extra_rounds`` more rounds run while
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
        res = program_cells(cells["bracket_length_mm"], cells["collision_length_top_mm"],
                            cells["collision_length_bottom_mm"], cells["boundary"], t_star,
                            material=mat, membrane=mem, t_request=t_req, factor=factor)
        cap, n_thinned = _thin_open_layers(cap, thick[-1], t_sim, t_star, t_last, frames_path,
                                           tol_mm)
        th = np.minimum(res["thickness"], cap)
        cap = np.where(np.isfinite(cap), th, cap)  # a capped layer never thickens again
        tables.update_cells(design_dir, cells, thickness_top_mm=th[:, 0],
                            thickness_bottom_mm=th[:, 1])
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
        tables.update_cells(design_dir, cells, thickness_top_mm=thick[best][:, 0],
                            thickness_bottom_mm=thick[best][:, 1])
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
        path = BRACKET_MODEL_FILE if material is None else material
        check_bracket_geometry(load_bracket_model(path), unit, str(path))  # (validates it)
    if membrane is None or isinstance(membrane, str | os.PathLike):
        validate_membrane_model_file(MEMBRANE_MODEL_FILE if membrane is None else membrane)
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
    return parse_physics("contact"), hit


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
    """Reuse the staging folder of an interrupted build with the same inputs, else start
    clean (:func:`pysolver.atomic.open_staging`: recognised by the stamp inside)."""
    if open_staging(staging, inputs_sha256=digest):
        _log(f"resuming the interrupted build in {staging}", progress)


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
