"""Part renderers and the part cache of the render stage.

Every part file is rendered by the chosen renderer (:data:`RENDERERS`): ``openscad`` runs
one OpenSCAD process per part in a pool of ``jobs`` workers, ``fast`` evaluates the same
files with openscad-evaluator (:mod:`pysolver.render.fast`), falling back to OpenSCAD
part by part, and ``auto`` is ``fast`` once :func:`fast_self_check` has found it to agree
with OpenSCAD on reference parts of the library.  Part STLs are cached under a hash of
the part file, the library and the renderer (:func:`part_key`).  The stage that unites
the parts into layers is :mod:`pysolver.render.layers`.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import resource
import shutil
import subprocess
import sys
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

from ..core.progress import Steps, say
from ..core.writes import atomic_file
from ..errors import ExternalToolError, InputError, MorphshellError
from ..params import tol as TOL
from . import fast as render_fast
from .scad_io import SCAD_DIR, Part, check_library
from .solids import load_stl, to_manifold

OPENSCAD_ENV = "MORPHSHELL_OPENSCAD"
"""Environment variable naming the OpenSCAD executable (default ``openscad`` on PATH)."""

OPENSCAD_TIMEOUT_S = 900.0
"""Seconds after which one part's OpenSCAD process is killed and reported as failed."""

RENDERERS = ("openscad", "fast", "auto")
"""Renderer backends of :func:`render_parts` (see there)."""

DEFAULT_RENDERER = "auto"
"""Backend used when none is given: ``auto``, i.e. the fast renderer once
:func:`fast_self_check` has matched it against OpenSCAD on reference parts of the library
in use (else OpenSCAD for everything), with per-part fallback to OpenSCAD.

The fast renderer agreed with OpenSCAD on every part of every built-in shape
(``bench/bench_render_fast.py``: volumes within 4.1e-5, symmetric difference within
9.8e-5 of the part volume, no failure).  It used to give non-watertight layer STLs more
often (8 of 18 layers vs 2 of 18 with OpenSCAD's parts, at bracket apexes where facing
arms of two parts crossed); since each bracket is drawn whole by one owner base and the
base polygons are turned away from every wall crossing their rim (``scad/base.scad``
``base_phase()``), every layer and preview of the six built-in shapes is watertight with
either renderer (``tests/test_builtin_stls.py`` for the fast one; all six rebuilt with
OpenSCAD too), and so were 72 of 72 stress layers (six shapes x their own and 5 random
thickness programs, fast renderer) against 10 of 72 before.  It renders ``petal``'s 767
parts in ~10 s instead of ~140 s."""

FAST_INSTALL_FIX = ("install it into the project's environment ('.venv/bin/pip install "
                    "openscad-evaluator'), or use the renderer 'openscad'.")


class RendererFallbackWarning(UserWarning):
    """The fast renderer failed on some parts, which OpenSCAD rendered instead."""

INSTALL_FIX = ("install OpenSCAD: 'sudo apt-get install openscad' (Debian/Ubuntu; any version "
               f">= 2019.05 works), or set {OPENSCAD_ENV}=/path/to/openscad.")

# stderr lines that make a part fail even when OpenSCAD exits 0: an unknown variable or
# an undefined operation silently renders wrong geometry (e.g. cube(undef) is a unit cube)
_FATAL_MARKERS = ("ERROR:", "unknown variable", "unknown module", "unknown function",
                  "undefined operation", "Ignoring unknown")

_BAR_INTERVAL_S = 2.0 if sys.stderr.isatty() else 15.0
"""Seconds between progress lines of the part pools: every 2 s on a terminal, every 15 s
in logs (CI, files); the last part always prints."""


# --------------------------------------------------------------------------------------------
# OpenSCAD

def find_openscad() -> str:
    """Path of the OpenSCAD executable.

    Raises
    ------
    ExternalToolError
        If OpenSCAD is not installed (message with the apt-get fix).
    """
    exe = os.environ.get(OPENSCAD_ENV, "openscad")
    path = shutil.which(exe)
    if path is None:
        raise ExternalToolError(f"OpenSCAD executable {exe!r} was not found: the render stage "
                                "needs it to turn the part files into STLs.", fix=INSTALL_FIX)
    return path


def openscad_version(exe: str) -> str:
    """Version line of ``openscad --version`` (e.g. ``OpenSCAD version 2021.01``)."""
    try:
        out = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as e:
        raise ExternalToolError(f"cannot run {exe} --version: {e}", fix=INSTALL_FIX) from None
    text = (out.stderr + out.stdout).strip().splitlines()
    return text[-1] if text else "unknown"


def library_digest(scad_dir) -> str:
    """sha256 over every ``*.scad`` file below ``scad_dir`` (relative path and content)."""
    scad_dir = Path(scad_dir)
    h = hashlib.sha256()
    for p in sorted(scad_dir.rglob("*.scad")):
        h.update(p.relative_to(scad_dir).as_posix().encode() + b"\0")
        h.update(p.read_bytes() + b"\0")
    return h.hexdigest()


def part_key(part_text: bytes, lib_digest: str, version: str) -> str:
    """Cache key of one part: sha256 of (part file, library digest, OpenSCAD version)."""
    h = hashlib.sha256(b"morphshell-part-v1\0")
    h.update(version.encode() + b"\0" + lib_digest.encode() + b"\0")
    h.update(part_text)
    return h.hexdigest()


def _run_openscad(exe: str, scad: Path, out_stl: Path) -> tuple[bool, float, str]:
    """Render one file; returns (ok, seconds, stderr)."""
    t0 = time.perf_counter()
    scad, out_stl = Path(scad).resolve(), Path(out_stl).resolve()  # OpenSCAD runs in scad.parent
    cmd = [exe, "--export-format", "binstl", "-o", str(out_stl), str(scad)]
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=OPENSCAD_TIMEOUT_S,
                             cwd=scad.parent)
        err, rc = res.stderr, res.returncode
    except subprocess.TimeoutExpired:
        return False, time.perf_counter() - t0, f"timed out after {OPENSCAD_TIMEOUT_S:.0f} s"
    dt = time.perf_counter() - t0
    fatal = [ln for ln in err.splitlines() if any(m in ln for m in _FATAL_MARKERS)]
    ok = rc == 0 and not fatal and out_stl.is_file() and out_stl.stat().st_size > 84
    if not ok and rc == 0 and not fatal:
        err += "\n(OpenSCAD wrote no geometry: the part is empty)"
    return ok, dt, err


def default_cache_dir(design_dir) -> Path:
    """``build/.cache/parts`` of the ``build`` folder holding the design, else the user's
    cache folder (``$XDG_CACHE_HOME/morphshell/parts``, by default
    ``~/.cache/morphshell/parts``): never a folder of the user's own beside the design."""
    design_dir = Path(design_dir).resolve()
    for p in design_dir.parents:  # (never the design folder itself, even if named build)
        if p.name == "build":
            return p / ".cache" / "parts"
    root = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(root) / "morphshell" / "parts"


def check_renderer(renderer) -> str:
    """Validate a renderer name (one of :data:`RENDERERS`).

    Raises
    ------
    InputError
        Naming the value and the choices.
    """
    if renderer not in RENDERERS:
        raise InputError(f"renderer must be one of {', '.join(RENDERERS)}, got {renderer!r}.",
                         fix="use --renderer openscad (Debian OpenSCAD), fast "
                             "(openscad-evaluator) or auto.")
    return renderer


def _openscad_pool(todo, *, exe, cache_dir, jobs, progress):
    """Render (Part, target STL) pairs with one OpenSCAD process per part.

    Returns ``seconds`` {name: OpenSCAD wall time} and ``failures`` [(Part, stderr)].
    """
    seconds: dict[str, float] = {}
    failures: list[tuple[Part, str]] = []
    if not todo:
        return seconds, failures

    def work(item):
        part, target = item
        result = []
        with contextlib.suppress(_NotRendered), atomic_file(target) as tmp:
            result = _run_openscad(exe, part.path, tmp)
            if not result[0]:
                raise _NotRendered  # the cache keeps no file for a failed part
        return (part, *result)

    bar = Steps("render", "OpenSCAD parts", len(todo), enabled=progress,
                every_s=_BAR_INTERVAL_S)
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(work, item) for item in todo]
        try:
            for fut in as_completed(futures):
                part, ok, dt, err = fut.result()
                if ok:
                    seconds[part.name] = dt
                else:
                    failures.append((part, err))
                bar.step()
        except BaseException:
            for f in futures:
                f.cancel()
            raise
    return seconds, failures


def _fast_pool(todo, *, cache_dir, jobs, progress):
    """Render (Part, target STL) pairs with openscad-evaluator worker processes.

    Returns ``seconds`` {name: evaluation wall time} and ``failures`` [(Part, message)].
    """
    seconds: dict[str, float] = {}
    failures: list[tuple[Part, str]] = []
    if not todo:
        return seconds, failures
    bar = Steps("render", "fast parts", len(todo), enabled=progress, every_s=_BAR_INTERVAL_S)
    lock = threading.Lock()

    def done(i, ans):
        with lock:
            bar.step()

    with contextlib.ExitStack() as stack:  # one temporary file per part, each atomic_file's
        files = [(part, stack.enter_context(_optional_file(target)))
                 for part, target in todo]
        answers = render_fast.render_files(
            [(p.path, tmp) for p, tmp in files], jobs=jobs,
            ast_dir=Path(cache_dir) / render_fast.AST_CACHE_DIRNAME, on_done=done)
        for (part, tmp), ans in zip(files, answers, strict=True):
            if ans["ok"] and tmp.is_file() and tmp.stat().st_size > 84:
                seconds[part.name] = float(ans["seconds"])
            else:
                tmp.unlink(missing_ok=True)  # not moved into the cache
                failures.append((part, ans["error"] or "(no geometry written)"))
    return seconds, failures


class _NotRendered(Exception):
    """A part the renderer failed on: its temporary file is dropped, the cache untouched."""


@contextlib.contextmanager
def _optional_file(target):
    """:func:`atomic_file` that stores nothing when the block removed the temporary file."""
    with contextlib.suppress(_NotRendered), atomic_file(target) as tmp:
        yield tmp
        if not tmp.exists():
            raise _NotRendered


def _failure_lines(failures, limit: int = 10, tail: int = 12) -> str:
    failures = sorted(failures, key=lambda pe: pe[0].name)
    lines = []
    for part, err in failures[:limit]:
        text = "\n      ".join(err.strip().splitlines()[-tail:])
        lines.append(f"  - {part.label()}: {part.path}\n      {text}")
    more = f"\n  ... and {len(failures) - limit} more" if len(failures) > limit else ""
    return "\n".join(lines) + more


def render_parts(parts, *, cache_dir, scad_dir=SCAD_DIR, jobs=None, progress=True,
                 exe=None, renderer=None) -> dict:
    """Render part files to STL through the cache, in parallel.

    Parameters
    ----------
    parts : list of pysolver.render.scad_io.Part
    cache_dir : path-like
        Folder of cached part STLs (``<key>.stl``), created if needed.
    scad_dir : path-like
        OpenSCAD library (hashed into every key).
    jobs : int, optional
        Parallel OpenSCAD processes / fast-renderer workers (default: CPU count).
    progress : bool
        ``[render] ... k/n  ETA`` lines on stderr (:class:`pysolver.core.progress.Steps`).
    exe : str, optional
        OpenSCAD executable (default :func:`find_openscad`).
    renderer : {"openscad", "fast", "auto"}, optional
        Backend (default :data:`DEFAULT_RENDERER`).  ``openscad``: Debian OpenSCAD,
        one process per part.  ``fast``: openscad-evaluator (:mod:`pysolver.render.fast`);
        a part it fails on is rendered by OpenSCAD instead (a
        :class:`RendererFallbackWarning` names it).  ``auto``: ``fast`` if it is
        importable and :func:`fast_self_check` agrees with OpenSCAD on reference parts
        of this library, else ``openscad``.  The cache key holds the renderer's name
        and version, so the two never share an STL.

    Returns
    -------
    result : dict
        ``stl`` {part name: cached STL path}, ``rendered`` / ``cached`` (counts),
        ``seconds`` {name: renderer wall time of the parts rendered now},
        ``wall_s`` (pool wall time), ``cpu_s`` (CPU time of the renderer processes),
        ``openscad`` (OpenSCAD version, None if it was not needed), ``jobs``,
        ``renderer`` (the backend used), ``renderer_requested``, ``renderer_version``,
        ``fallback`` {part name: why the fast renderer failed on it},
        ``self_check`` (:func:`fast_self_check` result for ``auto``, else None),
        ``self_check_s`` (its wall time, not in ``wall_s``).

    Raises
    ------
    ExternalToolError
        The renderer is missing, or failed on some parts (each named with its base id
        and layer, and the renderer's messages).  The parts that succeeded stay cached.
    InputError
        Bad ``jobs`` or ``renderer``.
    """
    requested = check_renderer(DEFAULT_RENDERER if renderer is None else renderer)
    digest = library_digest(scad_dir)
    cache_dir = Path(cache_dir)
    cache_dir.mkdir(parents=True, exist_ok=True)
    jobs = int(jobs) if jobs else (os.cpu_count() or 1)
    if jobs < 1:
        raise InputError(f"jobs must be >= 1, got {jobs}.", fix="omit jobs to use every CPU.")
    t_check = time.perf_counter()
    used, check, exe = _pick_renderer(requested, scad_dir=scad_dir, cache_dir=cache_dir,
                                      exe=exe, jobs=jobs, progress=progress)
    t_check = time.perf_counter() - t_check
    t0 = time.perf_counter()
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    exe, version = _renderer_version(used, exe)
    oversion = version if used == "openscad" else None
    stl, todo = _targets(parts, cache_dir, digest, version)
    seconds, failures, fallback, oversion = _render_todo(
        used, todo, parts, stl, exe=exe, oversion=oversion, cache_dir=cache_dir,
        digest=digest, jobs=jobs, progress=progress)
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    if failures:
        raise _parts_failed(failures, fallback, len(parts), len(todo), scad_dir)
    return {"stl": stl, "rendered": len(todo), "cached": len(parts) - len(todo),
            "seconds": seconds, "wall_s": wall, "cpu_s": cpu, "openscad": oversion,
            "jobs": jobs, "renderer": used, "renderer_requested": requested,
            "renderer_version": version, "fallback": fallback, "self_check": check,
            "self_check_s": t_check}


def _parts_failed(failures, fallback, n_parts: int, n_todo: int, scad_dir):
    """The error naming the parts OpenSCAD failed on."""
    first = " (the fast renderer had failed on them first)" if fallback else ""
    return ExternalToolError(
        f"OpenSCAD failed on {len(failures)} of {n_parts} parts{first} "
        f"({n_todo - len(failures)} rendered and cached, {n_parts - n_todo} were "
        "already cached):\n" + _failure_lines(failures),
        fix="open the named part file in OpenSCAD to see the error; if you edited the "
            f"library ({scad_dir}), fix the edit. Parts that rendered stay cached.")


def _renderer_version(used: str, exe):
    """(OpenSCAD executable or None, version string) of the backend ``used``."""
    if used == "openscad":
        exe = exe or find_openscad()
        return exe, openscad_version(exe)
    version = render_fast.version()
    if version is None:
        raise ExternalToolError("renderer 'fast' needs the Python package "
                                f"{render_fast.DIST}, which cannot be imported.",
                                fix=FAST_INSTALL_FIX)
    return exe, version


def _pick_renderer(requested: str, *, scad_dir, cache_dir, exe, jobs, progress):
    """The backend to use: ``requested``, or for ``auto`` the fast renderer when its
    self-check agrees with OpenSCAD.  Returns (backend, self-check or None, exe)."""
    if requested != "auto":
        return requested, None, exe
    exe = exe or find_openscad()
    check = fast_self_check(scad_dir=scad_dir, cache_dir=cache_dir, exe=exe, jobs=jobs,
                            progress=progress)
    used = "fast" if check["ok"] else "openscad"
    say("render", "", f"renderer auto -> {used}: {check['summary']}", progress)
    return used, check, exe


def _targets(parts, cache_dir: Path, digest: str, version: str):
    """Cache file of every part for a renderer version, and the (part, file) pairs not yet
    in the cache."""
    stl: dict[str, Path] = {}
    todo: list[tuple[Part, Path]] = []
    for p in parts:
        target = cache_dir / f"{part_key(p.path.read_bytes(), digest, version)}.stl"
        stl[p.name] = target
        if not target.is_file():
            todo.append((p, target))
    return stl, todo


def _render_todo(used, todo, parts, stl, *, exe, oversion, cache_dir, digest, jobs, progress):
    """Render the parts not in the cache with the backend ``used`` (the fast renderer's
    failures with OpenSCAD).  Returns (seconds, failures, fallback, OpenSCAD version)."""
    if used == "openscad":
        seconds, failures = _openscad_pool(todo, exe=exe, cache_dir=cache_dir, jobs=jobs,
                                           progress=progress)
        return seconds, failures, {}, oversion
    seconds, fast_failures = _fast_pool(todo, cache_dir=cache_dir, jobs=jobs, progress=progress)
    if not fast_failures:
        return seconds, [], {}, oversion
    fallback, oversion, failures = _openscad_fallback(
        fast_failures, parts, stl, seconds, exe=exe, cache_dir=cache_dir, digest=digest,
        jobs=jobs, progress=progress)
    return seconds, failures, fallback, oversion


def _openscad_fallback(fast_failures, parts, stl: dict, seconds: dict, *, exe, cache_dir,
                       digest, jobs, progress):
    """Render with OpenSCAD the parts the fast renderer failed on (a
    :class:`RendererFallbackWarning` names them); ``stl`` and ``seconds`` are updated.

    Returns
    -------
    fallback : dict -- {part name: why the fast renderer failed}
    oversion : str -- OpenSCAD's version
    failures : list -- (Part, message) OpenSCAD failed on too
    """
    fallback = {p.name: err.strip() for p, err in fast_failures}
    try:
        exe = exe or find_openscad()
        oversion = openscad_version(exe)
    except ExternalToolError:
        raise ExternalToolError(
            f"the fast renderer failed on {len(fast_failures)} of {len(parts)} parts, "
            "and OpenSCAD, which would render them instead, is not installed:\n"
            + _failure_lines(fast_failures),
            fix=INSTALL_FIX + " Parts that rendered stay cached.") from None
    names = sorted(fallback)
    warnings.warn(
        f"the fast renderer failed on {len(names)} of {len(parts)} parts "
        f"({', '.join(names[:5])}{', ...' if len(names) > 5 else ''}; first error: "
        f"{fallback[names[0]].splitlines()[-1] if fallback[names[0]] else '?'}); "
        "OpenSCAD renders them instead.", RendererFallbackWarning, stacklevel=4)
    redo_stl, redo = _targets([p for p, _err in fast_failures], cache_dir, digest, oversion)
    stl.update(redo_stl)
    more, failures = _openscad_pool(redo, exe=exe, cache_dir=cache_dir, jobs=jobs,
                                    progress=progress)
    seconds.update(more)
    return fallback, oversion, failures


_SELF_CHECKS: dict[tuple, dict] = {}
_SELF_CHECK_LOCK = threading.Lock()  # one self-check at a time; a second caller waits for it


def start_self_check(design_dir, *, renderer=None, scad_dir=None) -> threading.Thread | None:
    """Start the fast renderer's self-check of a later ``render_design(design_dir)`` in a
    background thread, so that it overlaps the stages before the render.

    The build's design, programming and simulation stages run on one core; the self-check
    (:func:`fast_self_check`) renders its reference parts with OpenSCAD and the fast renderer
    in child processes, one at a time here, on the other core.  The render stage's own call
    then waits for it and reads its result (memoised per process, and the reference renders
    are in the part cache).  If the background check fails, the render stage runs it again
    in the foreground, which raises the error there.

    Parameters
    ----------
    design_dir : path-like
        Design folder the render stage will render (its part cache is
        :func:`default_cache_dir`).
    renderer : {"openscad", "fast", "auto"}, optional
        The render stage's renderer (default :data:`DEFAULT_RENDERER`); only ``auto`` needs
        the self-check.
    scad_dir : path-like, optional
        OpenSCAD library (default: the repository's ``scad/``).

    Returns
    -------
    threading.Thread or None
        The running check, None when the renderer needs none.
    """
    if check_renderer(DEFAULT_RENDERER if renderer is None else renderer) != "auto":
        return None
    cache_dir = default_cache_dir(design_dir)
    scad = check_library(Path(scad_dir).resolve() if scad_dir else SCAD_DIR)

    def run():
        try:
            fast_self_check(scad_dir=scad, cache_dir=cache_dir, jobs=1)
        except MorphshellError:
            pass  # the render stage runs the check again and reports the error

    thread = threading.Thread(target=run, name="render-self-check", daemon=True)
    thread.start()
    return thread


def fast_self_check(*, scad_dir=SCAD_DIR, cache_dir, exe=None, jobs=None,
                    progress: bool = False) -> dict:
    """Compare the fast renderer with OpenSCAD on reference parts of a library.

    The reference parts (:func:`pysolver.render.fast.write_reference_parts`: top and
    bottom nodes with tilted bumpers, three brackets, alignment hole and marker pocket,
    an actuated node, both support frames, the marker dot and a specimen) are rendered by
    both backends through the part cache in ``<cache_dir>/selfcheck``; a part agrees
    when the volumes agree within ``Tolerances.self_check_volume_rtol`` and the volume of the
    symmetric difference is below ``Tolerances.self_check_symdiff_rtol`` of the part volume.
    Run once per process and (library, OpenSCAD, fast renderer) versions; later runs of
    a new process read both renders from the cache.  Thread-safe: a call made while another
    thread runs the check waits for it (:func:`start_self_check`).

    Parameters
    ----------
    scad_dir : path-like
        OpenSCAD library.
    cache_dir : path-like
        Part cache (the check uses its ``selfcheck`` subfolder).
    exe : str, optional
        OpenSCAD executable (default :func:`find_openscad`).
    jobs : int, optional
        Parallel processes.
    progress : bool
        Progress bars.

    Returns
    -------
    check : dict
        ``ok`` (bool), ``summary`` (one line), ``parts`` {name: {``volume_rel``,
        ``symdiff_rel``}}, ``max_volume_rel``, ``max_symdiff_rel``, ``failures``
        {name: message} (a backend failed on a reference part).

    Raises
    ------
    ExternalToolError
        OpenSCAD is missing.
    """
    fversion = render_fast.version()
    if fversion is None:
        return {"ok": False, "summary": f"{render_fast.DIST} is not importable", "parts": {},
                "max_volume_rel": None, "max_symdiff_rel": None, "failures": {}}
    exe = exe or find_openscad()
    oversion = openscad_version(exe)
    scad_dir = Path(scad_dir).resolve()
    digest = library_digest(scad_dir)
    memo = (digest, str(scad_dir), exe, oversion, fversion)
    with _SELF_CHECK_LOCK:
        if memo in _SELF_CHECKS:
            return dict(_SELF_CHECKS[memo])
        folder = Path(cache_dir) / "selfcheck"
        folder.mkdir(parents=True, exist_ok=True)
        jobs = int(jobs) if jobs else (os.cpu_count() or 1)
        parts = render_fast.write_reference_parts(folder / "parts", scad_dir)
        sets, failures = {}, {}
        for name, version in (("openscad", oversion), ("fast", fversion)):
            sets[name], bad = _reference_renders(name, version, parts, folder, digest, exe,
                                                 jobs, progress)
            failures.update(bad)
        per = {} if failures else _compare_renders(parts, sets, failures)
        _SELF_CHECKS[memo] = _self_check_result(parts, per, failures)
    return dict(_SELF_CHECKS[memo])


def _reference_renders(name, version, parts, folder, digest, exe, jobs, progress):
    """The reference parts rendered by one backend through the self-check's cache.

    Returns ({part name: STL path}, {"<part> (<backend>)": message} of the failures)."""
    targets = {p.name: folder / f"{part_key(p.path.read_bytes(), digest, version)}.stl"
               for p in parts}
    todo = [(p, targets[p.name]) for p in parts if not targets[p.name].is_file()]
    pool = _openscad_pool if name == "openscad" else _fast_pool
    kw = {"exe": exe} if name == "openscad" else {}
    _s, bad = pool(todo, cache_dir=folder, jobs=jobs, progress=progress, **kw)
    return targets, {f"{p.name} ({name})": err.strip() for p, err in bad}


def _compare_renders(parts, sets: dict, failures: dict) -> dict:
    """Relative volume and symmetric-difference volume of the two backends' renders per
    reference part; a render that is not a solid goes into ``failures``."""
    per = {}
    for p in parts:
        try:
            a = to_manifold(load_stl(sets["openscad"][p.name]), f"{p.name} (openscad)")
            b = to_manifold(load_stl(sets["fast"][p.name]), f"{p.name} (fast)")
        except ExternalToolError as e:
            failures[p.name] = str(e)
            continue
        va = a.volume()
        per[p.name] = {"volume_rel": abs(b.volume() - va) / va,
                       "symdiff_rel": ((a - b).volume() + (b - a).volume()) / va}
    return per


def _self_check_result(parts, per: dict, failures: dict) -> dict:
    """The self-check's verdict (:func:`fast_self_check`'s return value)."""
    mv = max((v["volume_rel"] for v in per.values()), default=None)
    ms = max((v["symdiff_rel"] for v in per.values()), default=None)
    ok = (not failures and len(per) == len(parts) and mv <= TOL.self_check_volume_rtol
          and ms <= TOL.self_check_symdiff_rtol)
    if failures:
        first = sorted(failures)[0]
        last = failures[first].splitlines()[-1] if failures[first] else ""
        summary = (f"self-check failed: a renderer failed on {len(failures)} reference "
                   f"part(s), e.g. {first}: {last}")
    else:
        summary = (f"self-check on {len(per)} reference parts "
                   f"{'passed' if ok else 'FAILED'}: volumes within {mv:.1e} (limit "
                   f"{TOL.self_check_volume_rtol:g}), symmetric difference <= {ms:.1e} of the "
                   f"volume (limit {TOL.self_check_symdiff_rtol:g})")
    return {"ok": bool(ok), "summary": summary, "parts": per, "max_volume_rel": mv,
            "max_symdiff_rel": ms, "failures": failures}


__all__ = ["render_parts", "find_openscad", "openscad_version", "library_digest", "part_key",
           "default_cache_dir", "RENDERERS", "DEFAULT_RENDERER", "OPENSCAD_ENV",
           "check_renderer", "fast_self_check", "start_self_check", "RendererFallbackWarning"]
