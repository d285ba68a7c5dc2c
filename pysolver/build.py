"""The whole pipeline for one shape: the stages of :data:`pysolver.stages.STAGES`, in order
(design -> program -> simulate [-> contact] [-> refine] -> render -> report; ``contact``:
simulated again with barrier contact when far-apart parts passed through each other,
:func:`pysolver.simulator.contact_if_needed`).

``build(source)`` runs every stage its :class:`~pysolver.stages.BuildOptions` ask for in a
staging folder ``build/.<name>.morphshell-staging/<name>``
(:func:`pysolver.core.staging.staging_dir`) and moves it to ``build/<name>`` only when all
stages have finished, so an interrupted build leaves the previous complete result (or
nothing).  The staging folder survives an interruption: a re-run with the same inputs
reuses it, which lets the simulation resume from its last checkpoint.  A lock per shape
keeps two builds of the same shape apart; different shapes build concurrently.

Every build writes ``summary.json`` with its key figures (counts, sizes, thickness range,
check results, timings), the versions of the project, OpenSCAD and key libraries
(:mod:`pysolver.core.provenance`), and a hash of the inputs.  :func:`rebuild` runs the stages
after the design stage again from an edited time landscape (the studio's *Run*).
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import shutil
import time
from pathlib import Path

import numpy as np

from . import tables
from .core.inputs import check_input_file
from .core.locks import build_lock
from .core.manifest import STAMP_NAME, file_digest, public_mode, read_stamp
from .core.ownership import audit, claim_output
from .core.progress import say
from .core.provenance import environment_versions, package_version, sha256_file
from .core.records import json_text
from .core.staging import (
    atomic_dir,
    open_staging,
    recover_stale,
    remove_staging,
    replace_dir,
    seal,
    staging_dir,
)
from .core.writes import atomic_write_text
from .design import check_design_options
from .design.surfaces import BUILTIN_SHAPES, check_spec
from .design.time_landscape import read_time_file, write_landscape
from .errors import EXIT_CHECK_FAILED, EXIT_OK, ExternalToolError, InputError, MorphshellError
from .material.model import check_bracket_geometry, load_bracket_model
from .params import BRACKET_MODEL_FILE, LIMITS, MEMBRANE_MODEL_FILE, SIM, UNIT_CELL
from .render import (
    DEFAULT_RENDERER,
    check_renderer,
    find_openscad,
    library_digest,
    openscad_version,
)
from .render.scad_io import SCAD_DIR
from .simulator import check_sim_span, print_verdict
from .stages import OPTIONS, STAGES, BuildOptions, StageContext, runner, stage
from .tables import read_bases, read_cells, read_record
from .temporal.membrane_model import validate_membrane_model_file

BUILD_ROOT = Path("build")


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


def rebuild_inputs_hash(old_inputs_sha256, landscape) -> tuple[str, str]:
    """``(inputs_sha256, landscape_sha256)`` of a :func:`rebuild` of the build whose inputs
    hash is ``old_inputs_sha256`` with ``landscape`` ((n_vertices,) float, s, rounded as
    ``time_landscape.csv`` keeps it: :func:`pysolver.tables.round_sig9`): the same for the
    same build and landscape, so a build of them made before is found by it."""
    land_sha = hashlib.sha256(np.asarray(landscape, float).astype("<f8").tobytes()).hexdigest()
    return hashlib.sha256(f"{old_inputs_sha256}\0{land_sha}".encode()).hexdigest(), land_sha


def inputs_hash(source: str, options: dict) -> str:
    """Hash of everything a build depends on: the source, options, material file, code version."""
    h = hashlib.sha256()
    p = Path(source)
    h.update(sha256_file(p).encode() if p.is_file() else source.encode())
    h.update(json_text(options, indent=None).rstrip("\n").encode())
    if options.get("material"):
        h.update(sha256_file(Path(options["material"])).encode())
    h.update(package_version("morphshell").encode())
    return h.hexdigest()


def tool_versions() -> dict:
    """Versions of the project, Python and the key libraries, the lock file's record
    (:func:`pysolver.core.provenance.environment_versions`) and OpenSCAD's version line."""
    v = environment_versions()
    try:
        v["openscad"] = openscad_version(find_openscad())
    except ExternalToolError:
        v["openscad"] = "not found"
    return v


def design_only(source: str, options: BuildOptions | None = None, **changes) -> dict:
    """Run only the design stage into ``options.out`` (default ``build/<name>``), atomically
    (``morphshell design``).

    Parameters
    ----------
    source : str
        As :func:`build`.
    options : BuildOptions, optional
        Only the design options, ``out`` and ``progress`` are read.
    **changes
        Fields of :class:`BuildOptions` to change.
    """
    opts = (options or BuildOptions()).replace(**changes)
    check_design_options(vertices=opts.vertices, time=opts.time, scale=opts.scale,
                         flattening=opts.flattening, size=opts.size, time_file=opts.time_file,
                         **({} if opts.params is None else {"params": opts.params}))
    name = shape_name(source)
    out = claim_output(opts.out or BUILD_ROOT / name, what="output folder",
                       inputs=[source] + [f for f in (opts.time_file, opts.thickness_file)
                                          if f])
    with build_lock(out):
        recover_stale(out)
        with atomic_dir(out) as tmp:
            ctx = StageContext(tmp, opts.replace(params=opts.params or UNIT_CELL), name=name,
                               source=source)
            result = runner(stage("design").run)(ctx)
    say("build", name, f"design -> {out}", opts.progress)
    return result


def check_build_options(options: BuildOptions) -> None:
    """Refuse bad build options before any stage runs (even options of skipped stages:
    a typo should not wait for the next full build to show).

    Raises
    ------
    InputError
        Naming the option, its value and the rule; ``ExternalToolError`` when rendering is
        requested and OpenSCAD is missing.
    """
    o = options
    if o.thickness_file is not None:  # (the program stage would overwrite them, unrecorded)
        raise InputError("a build programs the bracket thicknesses itself: thickness_file is "
                         "an option of the design stage only",
                         fix="morphshell design MESH --stencil --thickness-file FILE --out DIR, "
                             "then morphshell simulate DIR and morphshell report DIR")
    if o.jobs is not None and (int(o.jobs) != o.jobs or not 1 <= o.jobs <= LIMITS.max_jobs):
        raise InputError(f"--jobs must be a whole number from 1 to {LIMITS.max_jobs}, got "
                         f"{o.jobs}.",
                         fix="omit --jobs (JOBS=) to use every CPU, or give e.g. --jobs 2.")
    if o.refine is not None and (int(o.refine) != o.refine
                                 or not 0 <= o.refine <= LIMITS.max_refine):
        raise InputError(f"--refine must be a whole number from 0 to {LIMITS.max_refine}, "
                         f"got {o.refine}.", fix=f"use e.g. --refine {BuildOptions.refine} (the "
                                                 "default), or 0 for no refinement")
    if o.seed is not None and (isinstance(o.seed, bool) or not isinstance(o.seed, int)
                               or not 0 <= o.seed < 2**32):
        raise InputError(f"--seed must be a whole number from 0 to 2^32 - 1, got {o.seed!r}",
                         fix="give e.g. --seed 1")
    _check_span(o.t_end, o.dt, o.simulate)
    if o.render and check_renderer(o.renderer or DEFAULT_RENDERER) != "fast":
        find_openscad()  # missing OpenSCAD: say so now, not after the design stage


def _check_span(t_end, dt, simulate: bool) -> None:
    """``--t-end`` and ``--dt``: in range, not too many steps, ``t_end`` a whole number of
    steps (when the build simulates)."""
    for flag, v, lo, hi in (("--t-end", t_end, 0.0, LIMITS.max_t_end),
                            ("--dt", dt, LIMITS.min_dt, LIMITS.max_t_end)):
        if v is not None and not (math.isfinite(v) and v > 0 and lo <= v <= hi):
            raise InputError(f"{flag} must be a number of seconds from {lo:g} to {hi:g}, "
                             f"got {v}.",
                             fix=f"omit {flag} for the default, or give e.g. "
                                 f"{flag} {SIM.t_end if flag == '--t-end' else SIM.dt:g}.")
    steps = (t_end or SIM.t_end) / (dt or SIM.dt)
    if steps > LIMITS.max_steps:
        raise InputError(f"--t-end / --dt = {steps:.0f} simulation steps, more than "
                         f"{LIMITS.max_steps}.", fix="use a larger --dt or a shorter --t-end.")
    if simulate and (t_end is not None or dt is not None):
        check_sim_span(SIM.t_end if t_end is None else t_end, SIM.dt if dt is None else dt)


def build(source: str, options: BuildOptions | None = None, **changes) -> dict:
    """Build ``build/<name>/`` for a built-in shape or a mesh file.

    Parameters
    ----------
    source : str
        Built-in shape name (``petal``, ``saddle``, ``dome``, ``weave``, ``spiral``,
        ``regular``, with options such as ``regular:rows=2``) or a path to a mesh /
        stencil OBJ.
    options : BuildOptions, optional
        What to build (default :class:`~pysolver.stages.BuildOptions`: every stage).
    **changes
        Fields of :class:`~pysolver.stages.BuildOptions` to change, e.g.
        ``build("petal", render=False, refine=0)``.

    Returns
    -------
    summary : dict
        The content of ``summary.json`` plus ``exit_code``.

    Examples
    --------
    The design stage alone of a two-base patch (``tmp`` is a scratch folder; a full build
    of ``petal`` takes minutes):

    >>> from pysolver.build import build
    >>> s = build("regular:rows=1,cols=2", out=tmp / "tiny", program=False, render=False,
    ...           simulate=False, progress=False)
    >>> s["exit_code"], (tmp / "tiny" / "stencil.obj").is_file()
    (0, True)
    """
    opts = (options or BuildOptions()).replace(**changes)
    opts = opts.replace(params=UNIT_CELL if opts.params is None else opts.params)
    validate_model_files(opts.material, unit=opts.params)  # model files, before any stage
    check_design_options(vertices=opts.vertices, time=opts.time, scale=opts.scale,
                         flattening=opts.flattening, params=opts.params, size=opts.size,
                         time_file=opts.time_file)
    check_build_options(opts)
    name = shape_name(source)
    # absolute: stages may run external tools in other working directories (OpenSCAD)
    out = claim_output(opts.out or BUILD_ROOT / name, what="output folder",
                       inputs=[source, opts.material, opts.time_file])
    recorded = _recorded_options(opts)
    digest = inputs_hash(source, recorded)
    summary: dict = {"shape": name, "source": str(source), "options": recorded,
                     "inputs_sha256": digest, "stages": {}, "timings_s": {},
                     "stage_inputs": {},
                     "run": {"render": bool(opts.render), "renderer": opts.renderer,
                             "solver": opts.solver}}
    # A shape's own landscape gives the order of completion; its seconds are mapped onto
    # what the material can achieve when too many cells cannot reach them.  A user's
    # landscape is only checked.
    ctx = StageContext(staging_dir(out), opts, name=name, source=source, build=summary,
                       fit_landscape=opts.time is None and opts.time_file is None)
    _run_build(ctx, out, STAGES, digest)
    return _closing(summary, name, out, opts.progress)


def _recorded_options(o: BuildOptions) -> dict:
    """The options a build records (``summary.json``) and hashes: an option added later
    appears only when given, so the hash of earlier builds stays the same."""
    rec = dict(vertices=o.vertices, time=o.time, scale=o.scale, flattening=o.flattening,
               stencil=o.stencil, **o.given("seed"),
               material=str(o.material) if o.material else None, refine=o.refine,
               program=o.program, t_end=o.t_end, **o.given("size"))
    if o.time_file is not None:  # the file's content is an input: its hash goes into the digest
        rec["time_file"] = str(o.time_file)
        rec["time_file_sha256"] = read_time_file(o.time_file)[1]
    if o.params != UNIT_CELL:
        rec["params"] = o.params.to_dict()
    rec.update(o.given("dt"))
    if o.robust_timing:
        rec["robust_timing"] = True
    return rec


def _run_build(ctx: StageContext, out: Path, stages, digest: str, setup=None) -> None:
    """Run ``stages`` (those the options want) in the staging folder ``ctx.folder``, then
    seal it and move it to ``out``; a failed stage removes the staging folder (unless
    ``keep_failed``) and raises.  ``setup(staging)`` fills the staging folder first (a
    rebuild's copy of the design stage's files)."""
    opts, staging = ctx.options, ctx.folder
    t_build = time.perf_counter()
    with build_lock(out):
        recover_stale(out)
        if open_staging(staging, inputs_sha256=digest):
            say("build", ctx.name, f"resuming the interrupted build in {staging}",
                opts.progress)
        try:
            _run_stages(ctx, out, stages, setup, t_build)
        except OSError:   # a full disk, a quota...: the partial files go, freeing the space
            if not opts.keep_failed:
                remove_staging(staging)
            raise


def _run_stages(ctx, out: Path, stages, setup, t_build: float) -> None:
    """The body of :func:`_run_build`, in its staging folder ``ctx.folder``."""
    opts, staging = ctx.options, ctx.folder
    if setup is not None:
        setup(staging)
    steps = _StageRunner(ctx.build, ctx.name, out, staging, opts)
    ctx.substage = steps.run
    wanted = [s for s in stages if s.wanted(opts)]
    for s in wanted:  # early checks run on the core the first stages leave idle
        if s.prepare:
            runner(s.prepare)(staging, opts)
    for s in wanted:
        steps.run(s.name, runner(s.run), ctx)
    _finish(ctx.build, staging, out, t_build, opts)


class _StageRunner:
    """Runs one stage (or a step of one, :attr:`StageContext.substage`) into the build's
    summary: result, seconds (a step's seconds are not counted twice), progress lines; on
    a :class:`MorphshellError` it removes the staging folder (unless ``keep_failed``) and
    raises it again naming the stage and what was (not) kept."""

    def __init__(self, summary: dict, name: str, out: Path, staging: Path, opts):
        self.summary, self.name, self.out, self.staging = summary, name, out, staging
        self.keep_failed, self.progress = opts.keep_failed, opts.progress
        self.inner = 0.0  # seconds of the steps run inside the stage running now

    def run(self, key: str, fn, *a, **kw):
        say("build", self.name, f"{key} ...", self.progress, starts=key)
        t0, outer = time.perf_counter(), self.inner
        self.inner = 0.0
        try:
            res = fn(*a, **kw)
        except MorphshellError as e:
            raise self._failed(key, e) from e
        spent = time.perf_counter() - t0
        own, self.inner = spent - self.inner, outer + spent
        self.summary["timings_s"][key] = round(own, 3)
        self.summary["stages"][key] = res if isinstance(res, dict) else {}
        say("build", self.name, f"{key} done in {own:.1f} s", self.progress)
        return res

    def _failed(self, key: str, e: MorphshellError) -> MorphshellError:
        """``e`` again, naming the stage and what was (not) kept."""
        kept = (f"the previous complete build in {self.out} is unchanged"
                if self.out.exists() else f"nothing was written to {self.out}")
        if self.keep_failed:
            kept += f"; this build's partial files are in {self.staging}"
        else:
            remove_staging(self.staging)
            kept += "; this build's partial files were removed (add --debug to keep them)"
        problem, fix = e.problem, e.fix
        if not self.keep_failed:  # name files of the removed folder by their own names
            problem, fix = (m and m.replace(f"{self.staging}/", "").replace(
                str(self.staging), "the design folder") for m in (problem, fix))
        return type(e)(f"{key} stage: {problem}\n  ({kept})", fix=fix)


def _finish(summary: dict, staging: Path, out: Path, t_build: float, opts) -> None:
    """Write ``summary.json`` into the finished staging folder, stamp it and move it to
    ``out`` (replacing the previous build)."""
    summary["stage_inputs"] = _stage_inputs(staging, opts)
    summary["kept"] = _keep_skipped_outputs(out, staging, summary["stage_inputs"], opts)
    summary["timings_s"]["total"] = round(time.perf_counter() - t_build, 3)
    summary["versions"] = tool_versions()
    summary["figures"] = _key_figures(staging, summary["stages"])
    summary["output"] = str(out)
    atomic_write_text(staging / "summary.json", json_text(summary))
    seal(staging)
    public_mode(staging, recursive=True)
    replace_dir(staging, out)
    remove_staging(staging)


def _closing(summary: dict, name: str, out: Path, progress: bool) -> dict:
    """Say that the build is complete, print the verdict and set ``exit_code``."""
    stages = summary["stages"]
    say("build", name, f"build complete in {summary['timings_s']['total']:.1f} s -> {out}",
        progress)
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


def rebuild(folder, landscape, *, source: dict | None = None, progress: bool = True,
            out=None) -> dict:
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
        Progress lines on stderr (``[build] <name>: <stage> ...``, as a build).
    out : path-like, optional
        Build the edited landscape into this folder instead (a *variant* beside the
        original, e.g. ``build/petal-2``): ``folder`` is only read, and stays as it was.
        The folder must be new or one morphshell made (:func:`claim_output`).

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
    dest = folder if out is None else Path(out).absolute()
    old, opts = rebuild_options(folder, progress)
    V, _, _ = tables.read_stencil(folder / "stencil.obj")
    land = tables.round_sig9(check_landscape(landscape, len(V)))   # as time_landscape.csv keeps it
    if out is not None:
        check_variant_source(folder)
    claim_output(dest, what="build folder" if out is None else "variant folder",
                 inputs=() if out is None else (folder / "stencil.obj",))
    validate_model_files(opts.material, unit=tables.read_unit_cell(folder))
    digest, land_sha = rebuild_inputs_hash(old.get("inputs_sha256"), land)
    edit = {"made_by": "morphshell studio", "edited_from_tables_sha256":
            tables.tables_sha256(folder),
            **({} if out is None else {"variant_of": folder.name}), **(source or {})}
    summary: dict = {"shape": old.get("shape", folder.name), "source": old.get("source"),
                     "options": old["options"], "inputs_sha256": digest,
                     "stages": {k: v for k, v in old.get("stages", {}).items() if k == "design"},
                     "timings_s": {k: v for k, v in old.get("timings_s", {}).items()
                                   if k == "design"},
                     "stage_inputs": {}, "run": {"render": opts.render,
                                                 "renderer": opts.renderer,
                                                 "solver": opts.solver},
                     "edited": {"by": "morphshell studio", "landscape_sha256": land_sha,
                                "from_inputs_sha256": old.get("inputs_sha256"),
                                "before": report_figures(folder)}}
    ctx = StageContext(staging_dir(dest), opts, name=dest.name, build=summary)
    _run_build(ctx, dest, STAGES[1:], digest,
               setup=lambda staging: _copy_for_rebuild(folder, staging, land, edit,
                                                       variant=out is not None))
    return _closing(summary, dest.name, dest, progress)


def rebuild_options(folder: Path, progress: bool = False):
    """The summary of the build in ``folder`` and the options its stages ran with, which a
    :func:`rebuild` of it runs with (the studio plans its progress bar by them)."""
    old = read_record(folder / "summary.json")
    if not isinstance(old, dict) or not isinstance(old.get("options"), dict):
        raise InputError(f"{folder / 'summary.json'} is missing or unreadable: only a folder "
                         "made by 'morphshell build' can be built again from a landscape",
                         fix=f"build it first: morphshell build <shape> --out {folder}")
    opts, run = old["options"], old.get("run") or {}
    if not opts.get("program", True):
        raise InputError(f"{folder} was built without temporal programming (--no-program): a "
                         "landscape has nothing to program", fix="build it with programming")
    renderer = run.get("renderer") or old.get("stages", {}).get("render", {}).get("renderer")
    return old, BuildOptions(
        material=opts.get("material"), refine=int(opts.get("refine") or 0),
        robust_timing=bool(opts.get("robust_timing", False)),
        t_end=opts.get("t_end"), dt=opts.get("dt"), renderer=renderer,
        render=bool(run.get("render", (folder / "stl").is_dir())),
        solver=run.get("solver") or "fast", progress=progress)


def check_variant_source(folder: Path) -> None:
    """Refuse to make a variant of ``folder`` unless everything in it is morphshell's
    (:func:`~pysolver.core.ownership.audit`): a variant copies the build's files and records
    them as morphshell's, so a file of the user's there would be taken over.

    Raises
    ------
    InputError
        Naming the first foreign entries and the fix; nothing is written.
    """
    bad = audit(folder) if read_stamp(folder) is not None else [(folder, "no stamp")]
    if bad:
        names = ", ".join(f"{p if p == folder else p.relative_to(folder).as_posix()}: {why}"
                          for p, why in bad[:3])
        raise InputError(f"{folder} holds files morphshell did not write ({names}"
                         f"{f' and {len(bad) - 3} more' if len(bad) > 3 else ''}): a variant "
                         "copies the build's files and would record them as morphshell's",
                         fix=f"move those files out of {folder} (or build the shape again "
                             "into a new folder), then make the variant")


def _copy_for_rebuild(folder: Path, staging: Path, land: np.ndarray, edit: dict, *,
                      variant: bool = False) -> None:
    """The design stage's files of the build in ``folder``, with the new landscape
    (``time_landscape.csv``) and its record (``studio_landscape.json``), into ``staging``.

    Only the top-level files ``folder``'s stamp records are copied (never a user's file
    or a killed writer's temporary file), each checked against its recorded SHA-256 after
    the copy.  A ``variant`` (``folder`` is not the build being written, whose lock the
    caller holds) copies holding ``folder``'s build lock, so no build replaces it
    meanwhile.

    Raises
    ------
    InputError
        ``folder`` is being built, or a file changed since morphshell wrote it (the staging
        folder is then removed).
    """
    lock = build_lock(folder) if variant else contextlib.nullcontext()
    try:
        with lock:
            _copy_recorded(folder, staging)
    except InputError:
        remove_staging(staging)
        raise
    write_landscape(staging, land)
    atomic_write_text(staging / tables.LANDSCAPE_SOURCE,
                      json_text(edit, indent=1, sort_keys=False))


def _copy_recorded(folder: Path, staging: Path) -> None:
    """Copy the top-level files ``folder``'s stamp records (but :data:`REBUILD_DROPPED`)
    into ``staging``, each checked against its record after the copy."""
    m = read_stamp(folder) or {"files": {}, "prev": {}}
    for rel in sorted(m["files"]):
        if "/" in rel or rel in REBUILD_DROPPED:
            continue
        try:
            shutil.copy2(folder / rel, staging / rel, follow_symlinks=False)
            got = list(file_digest(staging / rel))
        except OSError:   # gone, or a link now: not the file morphshell wrote
            got = None
        if got not in (list(m["files"][rel]), list(m["prev"].get(rel) or [])):
            raise InputError(f"{folder / rel} changed since morphshell wrote it (while it "
                             "was being copied for the new build): nothing was built",
                             fix=f"check {folder / rel}; build the shape again if it is "
                                 "damaged, then run again")


def report_figures(folder) -> dict | None:
    """The headline figures of a build's report (``report/report.json``), None without one.

    Returns
    -------
    dict or None
        ``verdict``, ``reasons`` (list of ``{level, check, message}``), ``timing_rms_s``
        (the programmable cells: not clamped), ``timing_rms_all_s`` (every cell),
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
            "timing_rms_s": tm.get("rms_s"), "timing_rms_all_s": tm.get("rms_all_s"),
            "spearman": tm.get("spearman"),
            "n_clamped": tm.get("n_clamped"), "n_never_complete": tm.get("n_never_due"),
            "n_cells": tm.get("n_cells"), "shape_rms_mm": sh.get("rms_mm"),
            "shape_rms_pct": sh.get("rms_pct"),
            "refine_rounds": (r.get("provenance") or {}).get("refine_rounds"),
            "parts_fresh": parts.get("fresh") if parts.get("n_stl") else None,
            "tables_sha256": tb.get("sha256")}


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


# ------------------------------------------------------------------------------------------
# the outputs of skipped stages


def _skip_groups() -> dict:
    """``{option: stages}``: the stages with outputs to keep, by the option that turns them
    off (``render``: render; ``simulate``: simulate and report)."""
    groups: dict = {}
    for s in STAGES:
        if s.keeps:
            groups.setdefault(s.needs[0], []).append(s)
    return groups


def _dependency(name: str, opts: BuildOptions):
    """A value that the outputs of a stage depend on (:attr:`Stage.depends`)."""
    if name == "scad":
        return library_digest(SCAD_DIR)
    if name == "material":
        return (sha256_file(Path(opts.material)) if opts.material
                else "committed:" + package_version("morphshell"))
    return getattr(opts, name)


def _stage_inputs(folder: Path, opts: BuildOptions) -> dict:
    """Per skippable group (:func:`_skip_groups`), a hash of what its outputs are computed
    from: the design tables and stencil, plus the group's :attr:`Stage.depends`.  Equal
    hashes mean a skipped stage's earlier outputs are still right."""
    h = hashlib.sha256()
    for f in sorted(folder.glob("*.csv")) + [folder / "stencil.obj"]:
        h.update(f.name.encode() + b"\0" + (f.read_bytes() if f.is_file() else b"") + b"\0")
    design = h.hexdigest()
    out = {}
    for flag, group in _skip_groups().items():
        deps = sorted({d for s in group for d in s.depends})
        values = json_text({d: _dependency(d, opts) for d in deps}, indent=None)
        out[flag] = hashlib.sha256((design + values).encode()).hexdigest()
    return out


def _keep_skipped_outputs(out: Path, staging: Path, current: dict, opts: BuildOptions) -> dict:
    """Carry the previous build's outputs of a skipped stage into ``staging`` when what they
    were computed from is unchanged; otherwise say that they are dropped.

    Returns
    -------
    dict
        ``{option: "kept" | "dropped"}`` for every skipped group the previous build had run.
    """
    try:
        old = read_record(out / "summary.json").get("stage_inputs", {})
    except AttributeError:
        old = {}
    result = {}
    for flag, group in _skip_groups().items():
        present = [f for s in group for f in s.keeps if (out / f).is_dir()]
        if getattr(opts, flag) or not present:
            continue
        if old.get(flag) == current[flag]:
            for f in present:
                shutil.copytree(out / f, staging / f, copy_function=_link_or_copy)
            result[flag] = "kept"
            say("build", out.name, f"{flag} not run: kept the previous {', '.join(present)} "
                "(inputs unchanged)", opts.progress)
        else:
            result[flag] = "dropped"
            no = next(o.flags[0] for o in OPTIONS.values() if o.dest == flag)
            say("build", out.name, f"{flag} not run: the previous "
                f"{', '.join(p + '/' for p in present)} no longer match the design and are "
                f"dropped; re-run without {no} to make them again", opts.progress)
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


__all__ = ["build", "rebuild", "design_only", "check_build_options",
           "validate_model_files", "shape_name", "inputs_hash", "rebuild_inputs_hash",
           "tool_versions",
           "report_figures", "check_landscape", "REBUILD_DROPPED", "BUILD_ROOT"]
