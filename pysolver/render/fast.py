"""Fast renderer backend: the part files evaluated by ``openscad-evaluator``, in-process.

``openscad-evaluator`` (PyPI, MIT) is an interpreter of the OpenSCAD language whose
geometry kernel is manifold3d.  It reads the generated part files and the library
``scad/`` unchanged and is 10-20x faster per part than Debian's OpenSCAD 2021.01
(no process start, no CGAL).  It is a young project, so :mod:`pysolver.render`
uses it only as an option, cross-checks it against OpenSCAD (``renderer="auto"``
runs :func:`self_check` first) and falls back to OpenSCAD for every part it fails on.

Execution
---------
Parts are evaluated by ``jobs`` worker processes (``python -m pysolver.render.fast``),
each fed one part at a time over a pipe (one JSON line per request and per answer).
A worker parses each library file once and keeps it for every later part; a crash
(segfault) or a hang (``Limits.render_part_timeout_s``) costs only the part concerned,
which is reported as failed, and a fresh worker takes over the rest.  Workers keep the
parser's on-disk AST cache in ``<cache_dir>/.openscad-evaluator-ast`` instead of the
user's home folder.

Compatibility shim
------------------
``mirror([0, 0, 0])`` is the identity in OpenSCAD but an empty solid in
openscad-evaluator 1.8.1 (it calls ``Manifold.mirror`` with a zero normal).  The
library writes ``mirror([0, 0, layer == "top" ? 0 : 1])``, so every top-layer part
came out empty; :class:`_Evaluator` restores OpenSCAD's behaviour.

manifold3d keeps the boundaries between coplanar faces of different primitives (e.g.
the base disc's and a bracket arm's far face) and the vertices on them, which CGAL merges
away.  Rounded to float32 in the part STL, those vertices make the faces slightly
non-planar, and the layer union then left near-coincident vertices (the written layer
was not watertight).  :func:`evaluate_file` therefore returns
``solid.as_original().simplify(0)``: the same solid (volume unchanged to 1e-9) with
about OpenSCAD's vertex count.

The shim's version is part of :func:`version`, hence of every fast part's cache key.
"""

from __future__ import annotations

import json
import math
import os
import queue
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from ..core.child import python_argv
from ..core.provenance import package_version
from ..params import LIMITS
from .scad_io import Part, part_text

DIST = "openscad-evaluator"
"""PyPI distribution of the fast renderer (module ``openscad_evaluator``)."""

SHIM_VERSION = "2"
"""Version of this module's compatibility shim (in the cache key of every fast part)."""



AST_CACHE_DIRNAME = ".openscad-evaluator-ast"
"""Folder (inside the part cache) for the parser's on-disk AST cache of library files."""

# evaluator messages that make a part fail, as OpenSCAD's stderr does in render.py
_FATAL_MARKERS = ("ERROR:", "unknown variable", "unknown module", "unknown function",
                  "undefined operation", "Ignoring unknown", "use error")


# --------------------------------------------------------------------------------------------
# availability


def available() -> bool:
    """True when ``openscad_evaluator`` (and its parser) can be imported."""
    try:  # optional: probing whether the fast renderer's evaluator and parser are installed
        import openscad_evaluator  # noqa: F401  (optional, probed)
        import openscad_lalr_parser  # noqa: F401  (optional, probed)
    except Exception:   # ImportError, or a broken install raising anything at import
        return False
    return True


def version() -> str | None:
    """Renderer identity for cache keys and summaries, None if not importable.

    ``openscad-evaluator 1.8.1 (openscad-lalr-parser 2.1.0, manifold3d 3.5.4,
    morphshell shim 1)``: the geometry comes from manifold3d and the parse from the
    parser, so their versions are part of it.
    """
    if not available():
        return None
    v = package_version
    return (f"{DIST} {v(DIST)} (openscad-lalr-parser {v('openscad-lalr-parser')}, "
            f"manifold3d {v('manifold3d')}, morphshell shim {SHIM_VERSION})")


# --------------------------------------------------------------------------------------------
# in-process evaluation (runs in the worker)

_EVALUATOR_CLASS = None


def _evaluator_class():
    """``openscad_evaluator.Evaluator`` with OpenSCAD's ``mirror([0, 0, 0])`` (identity)."""
    global _EVALUATOR_CLASS
    if _EVALUATOR_CLASS is None:
        from openscad_evaluator import Evaluator  # optional: the fast renderer's OpenSCAD evaluator

        class _Evaluator(Evaluator):
            def _generate_transform(self, params, children, node):
                if params.get("name") == "mirror":
                    v = self._get_arg(params["args"], 0, "v", [1, 0, 0])
                    try:
                        zero = not any(float(x) for x in self._to_vec3(v))
                    except (TypeError, ValueError):
                        zero = False
                    if zero:   # OpenSCAD: mirror([0, 0, 0]) leaves its children as they are
                        params = dict(params, name="translate",
                                      args={"v": [0.0, 0.0, 0.0]})
                return super()._generate_transform(params, children, node)

        _EVALUATOR_CLASS = _Evaluator
    return _EVALUATOR_CLASS


def evaluate_file(scad) -> tuple:
    """Evaluate one ``.scad`` file to a solid.

    Parameters
    ----------
    scad : path-like
        Part file (``use`` / ``include`` resolved relative to it, as OpenSCAD does).

    Returns
    -------
    solid : manifold3d.Manifold
        Union of the file's top-level solids.
    messages : list of str
        echo / warning lines the evaluation printed.

    Raises
    ------
    RuntimeError
        Syntax error, failed assertion, a fatal warning (unknown variable, module or
        function, undefined operation), 2D-only or empty output.
    """
    import manifold3d as m3d  # heavy: manifold3d loads only for STL booleans

    # optional: the fast renderer's OpenSCAD evaluator
    from openscad_evaluator import EvalError, resolve_use_scopes

    # optional: the fast renderer's OpenSCAD parser
    from openscad_lalr_parser import getASTfromFile, getASTfromString

    # optional: the fast renderer's OpenSCAD parser
    from openscad_lalr_parser.nodes import IncludeStatement

    scad = Path(scad).resolve()
    text = scad.read_text(encoding="utf-8")
    # parse the part itself from its text: the parser's file cache is keyed by mtime only
    # and would write one pickle per part into its disk cache
    nodes = getASTfromString(text, origin=str(scad))
    if nodes is not None and any(isinstance(n, IncludeStatement) for n in nodes):
        nodes = getASTfromFile(str(scad))
    if nodes is None:
        raise RuntimeError(f"ERROR: syntax error in {scad}")
    msgs: list[str] = []
    nodes, _own, root = resolve_use_scopes(nodes, str(scad), msgs.append)
    ev = _evaluator_class()(echo_fn=msgs.append)
    try:
        bodies, _ids = ev.evaluate(nodes, root)
    except EvalError as e:
        raise RuntimeError("\n".join([*msgs, str(e)])) from None
    except RecursionError:
        raise RuntimeError("ERROR: recursion too deep while evaluating") from None
    fatal = [m for m in msgs if any(k in m for k in _FATAL_MARKERS)]
    if fatal:
        raise RuntimeError("\n".join(msgs))
    solids = [b.body for b in bodies if b.body is not None and b.role in ("normal", "show_only")]
    if any(b.body is None for b in bodies):
        raise RuntimeError("\n".join([*msgs, "ERROR: the part has 2D or open-mesh top-level "
                                      "geometry (not a solid)"]))
    solid = (m3d.Manifold.batch_boolean(solids, m3d.OpType.Add) if len(solids) > 1
             else solids[0] if solids else m3d.Manifold())
    if solid.status() != m3d.Error.NoError:
        raise RuntimeError("\n".join([*msgs, f"ERROR: invalid solid ({solid.status().name})"]))
    # merge the coplanar faces that came from different primitives and drop the vertices
    # inside them (CGAL's output has none): each such vertex is rounded to float32 on its
    # own in the STL, and in the layer union the no-longer-planar faces left
    # near-coincident vertices that broke watertightness of the written layer
    solid = solid.as_original().simplify(0.0)
    if solid.is_empty() or solid.volume() <= 0:
        raise RuntimeError("\n".join([*msgs, "(the evaluator produced no geometry: the part "
                                      "is empty)"]))
    return solid, msgs


def write_stl(solid, path) -> None:
    """Binary STL of a manifold3d solid (float32 coordinates, as OpenSCAD writes)."""
    import trimesh  # heavy: trimesh loads only for STL work

    mesh = solid.to_mesh64()
    V = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    F = np.asarray(mesh.tri_verts, dtype=np.int64)
    trimesh.Trimesh(V, F, process=False).export(str(path), file_type="stl")


def _serve(proto_out) -> None:
    """Worker loop: one JSON request per stdin line, one JSON answer per line on proto_out."""
    for line in sys.stdin:
        if not line.strip():
            continue
        req = json.loads(line)
        t0 = time.perf_counter()
        try:
            solid, _msgs = evaluate_file(req["scad"])
            write_stl(solid, req["out"])
            ans = {"ok": True, "error": ""}
        except Exception as e:   # any failure of the young evaluator is a per-part failure
            ans = {"ok": False, "error": f"{type(e).__name__}: {e}" if not
                   isinstance(e, RuntimeError) else str(e)}
        ans["seconds"] = time.perf_counter() - t0
        proto_out.write(json.dumps(ans) + "\n")
        proto_out.flush()


def main() -> None:
    """Entry point of a worker process (``python -m pysolver.render.fast``)."""
    # the protocol owns the original stdout; anything else printed (by Python or C code)
    # goes to stderr
    proto_out = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    import openscad_evaluator  # noqa: F401  (imported before the first part: cleaner timings)
    import trimesh  # noqa: F401  (the same: heavy, loaded once before the first part)

    proto_out.write(json.dumps({"ready": True}) + "\n")
    proto_out.flush()
    _serve(proto_out)


# --------------------------------------------------------------------------------------------
# reference parts of the self-check


def _reference_bumpers(layer: str) -> list:
    """Three bumpers (flat shell frame) with contact planes tilted by 0, +12 and -12 deg."""
    s = 1.0 if layer == "top" else -1.0
    out = []
    for d, tilt in ((0.0, 0.0), (120.0, 12.0), (240.0, -12.0)):
        u = (math.cos(math.radians(d)), math.sin(math.radians(d)))
        c, z = math.cos(math.radians(tilt)), math.sin(math.radians(tilt))
        out.append([d, [2.6 * u[0], 2.6 * u[1], s * 2.3], [c * u[0], c * u[1], s * z]])
    return out


def write_reference_parts(folder, scad_dir) -> list:
    """Write the self-check's reference part files (every module the parts use).

    Parameters
    ----------
    folder : path-like
        Output folder (created); a file is rewritten only if its text changed.
    scad_dir : path-like
        OpenSCAD library.

    Returns
    -------
    parts : list of pysolver.render.scad_io.Part
        ``ref_node_top`` (alignment hole, tilted bumpers, three brackets of different
        thickness), ``ref_node_bottom``, ``ref_actuated_top`` (brackets opened to spans),
        ``ref_frame_top``, ``ref_frame_bottom``, ``ref_marker``, ``ref_specimen``.
    """
    folder, scad_dir = Path(folder), Path(scad_dir).resolve()
    folder.mkdir(parents=True, exist_ok=True)
    brackets = [[0, 7.0, 0.45], [120, 6.5, 0.3], [240, 8.2, 0.65]]
    outline = [[-12.0, -9.0], [10.0, -11.0], [15.0, 2.0], [4.0, 12.5], [-13.0, 8.0]]
    connectors = [[[-9.0, -6.5], -100.0, 11.5], [[11.0, 0.5], 10.0, 11.7]]  # lengths, mm
    specs = [
        ("ref_node_top", "node", "top", "unit_node.scad", "unit_node",
         dict(centre=[1.25, -0.5], layer="top", bumpers=_reference_bumpers("top"),
              brackets=brackets, alignment=True, marker=True)),
        ("ref_node_bottom", "node", "bottom", "unit_node.scad", "unit_node",
         dict(centre=[-3.0, 2.0], layer="bottom", bumpers=_reference_bumpers("bottom"),
              brackets=brackets, alignment=False, marker=True)),
        ("ref_actuated_top", "actuated", "top", "unit_node.scad", "unit_node",
         dict(centre=[0.0, 0.0], layer="top", bumpers=_reference_bumpers("top"),
              brackets=[b + [span] for b, span in zip(brackets, (5.0, 6.2, 4.1), strict=True)],
              alignment=False, marker=True)),
        ("ref_frame_top", "frame", "top", "support_frame.scad", "support_frame",
         dict(outline=outline, connectors=connectors, layer="top")),
        ("ref_frame_bottom", "frame", "bottom", "support_frame.scad", "support_frame",
         dict(outline=outline, connectors=connectors, layer="bottom")),
        ("ref_marker", "marker", None, "holes.scad", "marker_dot", {}),
        ("ref_specimen", "specimen", None, "specimen.scad", "specimen", dict(l=7, h=0.45)),
    ]
    parts = []
    for name, kind, layer, lib, module, kw in specs:
        text = part_text(f"{name}: fast-renderer self-check reference", scad_dir / lib, module,
                         **kw)
        path = folder / f"{name}.scad"
        if not path.is_file() or path.read_text() != text:
            path.write_text(text, newline="\n")
        parts.append(Part(name, kind, layer, -1, path))
    return parts


# --------------------------------------------------------------------------------------------
# the pool (runs in the caller)


class _Worker:
    """One worker process and its stderr log."""

    def __init__(self, ast_dir: Path | None):
        env = dict(os.environ)
        if ast_dir is not None:
            env["OPENSCAD_PARSER_CACHE_DIR"] = str(ast_dir)
        self.log = tempfile.TemporaryFile(mode="w+b")
        self.proc = subprocess.Popen(
            python_argv("pysolver.render.fast"), stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=self.log, text=True, bufsize=1, env=env)
        self.ready = False

    def _readline(self, timeout: float, request: str | None = None) -> tuple[str, bool]:
        """(line, timed out): send ``request`` (if any) and read one answer line."""
        fired = threading.Event()

        def kill():
            fired.set()
            self.proc.kill()

        timer = threading.Timer(timeout, kill)
        timer.start()
        try:
            if request is not None:
                self.proc.stdin.write(request + "\n")
                self.proc.stdin.flush()
            line = self.proc.stdout.readline()
        except (BrokenPipeError, OSError):
            line = ""
        finally:
            timer.cancel()
        return line, fired.is_set()

    def ask(self, scad: Path, out: Path, timeout: float) -> dict:
        """Render one part; a dead or stuck worker gives ``ok False`` and must be replaced."""
        line, late = "", False
        if not self.ready:   # the per-part timeout starts once the worker has imported
            line, late = self._readline(LIMITS.render_startup_timeout_s)
            self.ready = bool(line)
            what = f"did not start within {LIMITS.render_startup_timeout_s:.0f} s"
        if self.ready:
            line, late = self._readline(timeout, json.dumps({"scad": str(scad),
                                                             "out": str(out)}))
            what = f"timed out after {timeout:.0f} s"
        if line:
            return json.loads(line)
        self.proc.kill()
        rc = self.proc.wait()
        why = what if late else f"worker process died (exit code {rc})"
        return {"ok": False, "seconds": float("nan"), "dead": True,
                "error": f"fast renderer {why}\n{self.stderr_tail()}"}

    def stderr_tail(self, n: int = 12) -> str:
        self.log.seek(0)
        lines = self.log.read().decode(errors="replace").strip().splitlines()
        return "\n".join(lines[-n:])

    def close(self) -> None:
        try:
            if self.proc.poll() is None:
                self.proc.stdin.close()
                try:
                    self.proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait()
        except OSError:
            self.proc.kill()
        finally:
            self.log.close()


def render_files(items, *, jobs: int, ast_dir=None, on_done=None,
                 timeout: float = LIMITS.render_part_timeout_s) -> list[dict]:
    """Evaluate part files to STL with ``jobs`` worker processes.

    Parameters
    ----------
    items : list of (path-like, path-like)
        (part ``.scad`` file, STL to write).
    jobs : int
        Worker processes (at most ``len(items)``).
    ast_dir : path-like, optional
        Folder for the parser's on-disk AST cache (default: the parser's own).
    on_done : callable, optional
        Called with (index, answer) from a pool thread as each part finishes.
    timeout : float, s
        Per part.

    Returns
    -------
    answers : list of dict
        Per item: ``ok`` (bool), ``seconds`` (evaluation wall time), ``error`` (text).
    """
    items = [(Path(s), Path(o)) for s, o in items]
    answers: list[dict | None] = [None] * len(items)
    if not items:
        return []
    todo: queue.SimpleQueue = queue.SimpleQueue()
    for i in range(len(items)):
        todo.put(i)
    ast_dir = Path(ast_dir) if ast_dir is not None else None
    if ast_dir is not None:
        ast_dir.mkdir(parents=True, exist_ok=True)
    workers: list[_Worker] = []
    lock = threading.Lock()

    def slot():
        w = None
        try:
            while True:
                try:
                    i = todo.get_nowait()
                except queue.Empty:
                    return
                if w is None:
                    w = _Worker(ast_dir)
                    with lock:
                        workers.append(w)
                ans = w.ask(*items[i], timeout)
                if ans.pop("dead", False):
                    w.close()
                    w = None
                answers[i] = ans
                if on_done is not None:
                    on_done(i, ans)
        finally:
            if w is not None:
                w.close()

    threads = [threading.Thread(target=slot, daemon=True)
               for _ in range(max(1, min(int(jobs), len(items))))]
    try:
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:   # interrupted: stop every worker this call started
        with lock:
            for w in workers:
                if w.proc.poll() is None:
                    w.proc.kill()
    return [a if a is not None else {"ok": False, "seconds": float("nan"),
                                     "error": "not rendered (interrupted)"} for a in answers]


if __name__ == "__main__":
    main()
