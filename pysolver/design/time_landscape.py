"""Time landscape: requested completion time (s) per stencil vertex.

Sources (argument ``time`` of :func:`resolve_time`):

* ``None`` -- the shape's default (built-in shapes) or :data:`DEFAULT_TIME_S`;
* a number -- constant;
* a string expression of the target coordinates, e.g. ``"30 + 0.5*z"``, evaluated
  safely: only numbers, the names ``x, y, z, r`` (mm, stencil vertices, centred)
  plus ``xmin..zmax``-style extents, and whitelisted numpy functions are allowed;
* ``"vertex"`` / ``"vertex:<name>"`` -- a scalar per vertex of the input mesh (a PLY
  vertex property such as ``quality`` or ``time_s``), in seconds;
* ``"color:<t0>:<t1>"`` -- the input mesh's vertex colour (luminance 0..1) mapped to
  the range t0..t1 s;
* an array -- one value per stencil vertex, or per input-mesh vertex (interpolated).

Per-input-vertex values are interpolated onto the stencil by barycentric
coordinates of the closest point on the input mesh.
"""

from __future__ import annotations

import ast
import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import igl
import numpy as np

from .. import tables
from ..errors import InputError
from ..params import LIMITS, SEQUENCING
from ..params import tol as TOL
from .sequencing import sequencing_landscape

DEFAULT_TIME_S = 60.0

# The closed language of time expressions: numbers, the names below, arithmetic,
# comparisons and these functions with exactly this many positional arguments.  The
# expression is parsed with ``ast`` and walked by :func:`_evaluate`; it is never compiled or
# handed to ``eval``, and numpy's keyword or extra positional arguments (``out=``,
# ``where=``, ``sign(x, x)``), attributes and subscripts cannot be written.
_FUNCS = {  # name: (numpy function, arity)
    **{n: (getattr(np, n), 1) for n in (
        "sin", "cos", "tan", "arcsin", "arccos", "arctan", "sinh", "cosh", "tanh", "exp",
        "log", "log10", "sqrt", "abs", "floor", "ceil", "round", "sign", "degrees",
        "radians")},
    **{n: (getattr(np, n), 2) for n in ("arctan2", "minimum", "maximum", "hypot", "mod")},
    "clip": (np.clip, 3),
    "where": (np.where, 3),
}
_CONSTS = {"pi": np.pi, "e": np.e}
_BINOPS = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply,
           ast.Div: np.true_divide, ast.Pow: np.power, ast.Mod: np.mod,
           ast.FloorDiv: np.floor_divide}
_UNARYOPS = {ast.USub: np.negative, ast.UAdd: np.positive}
_CMPOPS = {ast.Lt: np.less, ast.LtE: np.less_equal, ast.Gt: np.greater,
           ast.GtE: np.greater_equal, ast.Eq: np.equal, ast.NotEq: np.not_equal}
_VARIABLES = ("x", "y", "z", "r", *(a + m for a in "xyz" for m in ("min", "max")))
_NAMES = {*_VARIABLES, *_CONSTS}
MAX_EXPRESSION_CHARS = 2000
"""Longest time expression accepted (characters)."""
_HELP = ("a numpy-style expression of x, y, z, r (mm) giving seconds, e.g. \"30 + 0.5*z\"; "
         "names: x y z r xmin..zmax pi e; functions: "
         + ", ".join(f"{n}/{k}" for n, (_f, k) in sorted(_FUNCS.items())))


def _refuse(expr: str, what: str):
    raise InputError(f"time expression {expr!r}: {what}", fix=f"write {_HELP}")


def parse_expression(expr: str) -> ast.Expression:
    """Parse a time expression and check that it stays in the closed language (see
    :data:`_FUNCS`), without evaluating it: cheap, so options can be checked before any
    stage runs.

    Raises
    ------
    InputError
        Syntax error, unknown name, a call with the wrong number of arguments or with keyword
        arguments, or any construct other than numbers, names, arithmetic, comparisons and
        the whitelisted functions.
    """
    if not isinstance(expr, str):
        raise InputError(f"time expression {expr!r} is not text", fix=f"write {_HELP}")
    if len(expr) > MAX_EXPRESSION_CHARS:
        _refuse(expr[:40] + "...", f"longer than {MAX_EXPRESSION_CHARS} characters")
    try:
        tree = ast.parse(expr.strip(), mode="eval")
    except SyntaxError as e:
        _refuse(expr, f"syntax error ({e.msg})")
    except (ValueError, RecursionError, MemoryError) as e:  # null bytes, absurd nesting
        _refuse(expr, f"cannot be parsed ({type(e).__name__})")
    for node in ast.walk(tree):
        if isinstance(node, (ast.Expression, ast.Load, *_BINOPS, *_UNARYOPS, *_CMPOPS)):
            continue
        if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
            continue
        if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARYOPS:
            continue
        if isinstance(node, ast.Compare) and all(type(o) in _CMPOPS for o in node.ops):
            continue
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
                _refuse(expr, f"only numbers are allowed as constants, not {node.value!r}")
            continue
        if isinstance(node, ast.Name):
            if node.id not in _NAMES and node.id not in _FUNCS:
                _refuse(expr, f"unknown name {node.id!r}")
            continue
        if isinstance(node, ast.Call):
            name = node.func.id if isinstance(node.func, ast.Name) else None
            if name not in _FUNCS:
                _refuse(expr, "only the listed functions may be called")
            if node.keywords:
                _refuse(expr, f"{name}() takes no keyword arguments")
            arity = _FUNCS[name][1]
            if len(node.args) != arity or any(isinstance(a, ast.Starred) for a in node.args):
                _refuse(expr, f"{name}() takes exactly {arity} argument"
                              f"{'s' if arity > 1 else ''}, got {len(node.args)}")
            continue
        _refuse(expr, f"{type(node).__name__} is not allowed")
    for node in ast.walk(tree):  # a function name is only valid as the callee of a call
        if isinstance(node, ast.Name) and node.id in _FUNCS and node.id not in _NAMES:
            parents = [p for p in ast.walk(tree) if isinstance(p, ast.Call) and p.func is node]
            if not parents:
                _refuse(expr, f"{node.id} is a function; call it, e.g. {node.id}(x)")
    return tree


def _evaluate(node, names: dict):
    """Value of a checked expression node; numbers are floats (Python ints have unbounded
    size, so "9**9**9" would run for minutes; float arithmetic overflows at once)."""
    if isinstance(node, ast.Expression):
        return _evaluate(node.body, names)
    if isinstance(node, ast.Constant):
        return float(node.value)
    if isinstance(node, ast.Name):
        return names[node.id]
    if isinstance(node, ast.BinOp):
        if isinstance(node.op, (ast.Div, ast.FloorDiv, ast.Mod)):
            den = np.asarray(_evaluate(node.right, names))
            if np.any(den == 0):
                raise ZeroDivisionError("division by zero")
        return _BINOPS[type(node.op)](_evaluate(node.left, names), _evaluate(node.right, names))
    if isinstance(node, ast.UnaryOp):
        return _UNARYOPS[type(node.op)](_evaluate(node.operand, names))
    if isinstance(node, ast.Compare):  # a < b < c means (a < b) & (b < c), as in Python
        left, out = _evaluate(node.left, names), True
        for op, right_node in zip(node.ops, node.comparators, strict=True):
            right = _evaluate(right_node, names)
            out = np.logical_and(out, _CMPOPS[type(op)](left, right))
            left = right
        return out.astype(float)
    if isinstance(node, ast.Call):
        fn, _arity = _FUNCS[node.func.id]
        return fn(*(_evaluate(a, names) for a in node.args))
    raise AssertionError(type(node).__name__)  # parse_expression admits nothing else


def check_time_option(time) -> None:
    """Check the ``time`` option before any stage runs: a constant must be a finite,
    non-negative number of seconds; an expression must parse (see :func:`parse_expression`).
    Arrays and per-vertex sources are checked when they are resolved."""
    if isinstance(time, bool):
        raise InputError(f"time={time!r}: expected seconds, an expression or an array")
    if isinstance(time, str):
        s = time.strip()
        try:
            c = float(s)
        except ValueError:
            if not s.startswith(("vertex", "color")):
                parse_expression(s)
            return
    elif isinstance(time, (int, float, np.integer, np.floating)):
        s, c = repr(time), float(time)
    else:
        return
    if not np.isfinite(c):
        raise InputError(f"time {s!r}: NaN/inf is not a time", fix="give finite times in seconds")
    if c < 0:
        raise InputError(f"time {s!r}: negative time {c:g} s",
                         fix="times are seconds under water, >= 0")


def evaluate_expression(expr: str, V: np.ndarray) -> np.ndarray:
    """Evaluate a time expression on target coordinates, safely.

    Parameters
    ----------
    expr : str
        E.g. ``"30 + 0.5*z"``, ``"40 + 20*tanh(r/30)"``.
    V : (n, 3) float, mm
        Stencil target vertices.

    Returns
    -------
    t : (n,) float, s
    """
    tree = parse_expression(expr)
    V = np.array(V, dtype=float)  # a private copy: nothing in the expression can reach V
    x, y, z = V[:, 0], V[:, 1], V[:, 2]
    names = {"x": x, "y": y, "z": z, "r": np.hypot(x, y), **_CONSTS}
    for a, col in zip("xyz", (x, y, z), strict=True):
        names[a + "min"], names[a + "max"] = float(col.min()), float(col.max())
    for v in names.values():
        if isinstance(v, np.ndarray):
            v.flags.writeable = False
    try:
        with np.errstate(over="raise", divide="ignore", invalid="ignore", under="ignore"):
            val = _evaluate(tree, names)
        return np.broadcast_to(np.asarray(val, dtype=float), (len(V),)).copy()
    except (ArithmeticError, TypeError, ValueError, RecursionError) as e:
        raise InputError(f"time expression {expr!r} cannot be evaluated: "
                         f"{type(e).__name__}: {e}", fix=f"write {_HELP}") from None


def interpolate_to_stencil(values, V_src, F_src, V_stencil) -> np.ndarray:
    """Interpolate per-vertex values of a source mesh onto points (closest point, barycentric)."""
    values = np.asarray(values, float)
    V_src = np.asarray(V_src, float)
    F_src = np.asarray(F_src, dtype=np.int64)
    _, fi, C = igl.point_mesh_squared_distance(np.asarray(V_stencil, float), V_src, F_src)
    P = V_src[F_src[fi]]
    # barycentric coordinates of C in triangle P (least squares, robust to tiny offsets)
    e1, e2, w = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0], C - P[:, 0]
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    w1, w2 = (w * e1).sum(1), (w * e2).sum(1)
    den = d11 * d22 - d12**2
    b1 = (d22 * w1 - d12 * w2) / den
    b2 = (d11 * w2 - d12 * w1) / den
    b0 = 1 - b1 - b2
    vals = values[F_src[fi]]
    return b0 * vals[:, 0] + b1 * vals[:, 1] + b2 * vals[:, 2]


def validate_time(t, n: int, what: str = "time landscape") -> np.ndarray:
    """Check a per-vertex time array: length n, finite, >= 0; warn-free copy as float."""
    t = np.asarray(t, dtype=float).ravel()
    if len(t) != n:
        raise InputError(f"{what}: {len(t)} values for {n} stencil vertices",
                         fix="give one time per stencil vertex (or per input-mesh vertex)")
    bad = np.flatnonzero(~np.isfinite(t))
    if len(bad):
        raise InputError(f"{what}: NaN/inf at vertex {bad[0]} ({len(bad)} values)",
                         fix="give finite times in seconds")
    neg = np.flatnonzero(t < 0)
    if len(neg):
        raise InputError(f"{what}: negative time {t[neg[0]]:.3g} s at vertex {neg[0]}",
                         fix="times are seconds under water, >= 0")
    return t


TIME_FILE_ATTRIBUTE = "time_file"
"""Name of the vertex attribute that carries ``--time-file`` values on the input mesh, so
they reach the stencil by the same path as a PLY vertex property (``time='vertex:...'``)."""


def read_option_text(path, option: str, fix: str) -> tuple[str, bytes]:
    """The text of a small input file given with a command-line option (``--time-file``,
    ``--thickness-file``): a regular file of at most :attr:`Limits.max_time_file_bytes`,
    UTF-8 (a BOM is dropped).

    Returns
    -------
    text : str
    data : bytes -- the file's bytes (for its hash)

    Raises
    ------
    InputError
        Missing, not a regular file, too large, not UTF-8; naming ``option`` and ``fix``.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{option} {path}: no such file" if not path.exists() else
                         f"{option} {path}: not a regular file", fix=fix)
    size = path.stat().st_size
    if size > LIMITS.max_time_file_bytes:
        raise InputError(f"{option} {path}: {size} bytes, more than "
                         f"{LIMITS.max_time_file_bytes} bytes", fix=fix)
    data = path.read_bytes()
    try:
        return data.decode("utf-8-sig"), data
    except UnicodeDecodeError as e:
        raise InputError(f"{option} {path}: not UTF-8 text ({e.reason} at byte {e.start})",
                         fix=fix) from None


def read_time_file(path) -> tuple[np.ndarray, str]:
    """Read a ``--time-file``: CSV, one value (s) per vertex of the input mesh in file order.

    One column; an optional header line (any text that is not a number, e.g. ``time_s``);
    blank lines are skipped.  Values are parsed as numbers (never evaluated) and checked
    like every landscape (:func:`validate_time`: finite, >= 0) and against the longest
    simulation, :attr:`pysolver.params.Limits.max_t_end`.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    values : (k,) float, s
    sha256 : str
        Hash of the file's bytes (recorded in ``design.json``).

    Raises
    ------
    InputError
        Missing, unreadable, too large or non-text file; more than one column; a value
        that is not a number (named by line); a value outside the time limits.
    """
    path = Path(path)
    fix = ("write one time in seconds per input-mesh vertex, in the mesh file's vertex order, "
           "one per line (an optional header line such as 'time_s' first)")
    text, data = read_option_text(path, "--time-file", fix)
    values, first = [], True
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        fields = line.replace(";", ",").replace("\t", ",").split(",")
        if len(fields) != 1:
            raise InputError(f"--time-file {path}:{lineno}: {len(fields)} columns "
                             f"({line[:40]!r}); expected one value per line", fix=fix)
        try:
            v = float(line)
        except ValueError:
            if first:  # a header
                first = False
                continue
            raise InputError(f"--time-file {path}:{lineno}: {line[:40]!r} is not a number "
                             "of seconds", fix=fix) from None
        first = False
        values.append(v)
    if not values:
        raise InputError(f"--time-file {path}: no values", fix=fix)
    t = np.asarray(values, float)
    bad = np.flatnonzero(~np.isfinite(t) | (t < 0) | (t > LIMITS.max_t_end))
    if len(bad):
        validate_time(t, len(t), f"--time-file {path}")  # names NaN/inf and negative times
        raise InputError(f"--time-file {path}: {t[bad[0]]:g} s at vertex {bad[0]} is beyond "
                         f"the longest simulation ({LIMITS.max_t_end:g} s)",
                         fix="give completion times in seconds under water (the paper's are "
                             f"{SEQUENCING.times_s[0]:g}-{SEQUENCING.times_s[1]:g} s)")
    return t, hashlib.sha256(data).hexdigest()


def time_file_per_vertex(values, mesh, path="--time-file") -> np.ndarray:
    """``--time-file`` values (file order) as one value per vertex of a loaded input mesh.

    Parameters
    ----------
    values : (k,) float, s
        One value per vertex of the mesh file, in the file's order.
    mesh : pysolver.design.mesh_input.InputMesh
        The loaded input; its vertices may have been welded or unreferenced ones removed
        (``file_index`` maps them to the file's order).
    path : str
        Named in messages.

    Returns
    -------
    t : (n,) float, s
        ``t[i]`` = value of the file vertex that became mesh vertex ``i``.

    Raises
    ------
    InputError
        When the count is not the mesh file's vertex count.
    """
    values = np.asarray(values, float).ravel()
    n_file = int(getattr(mesh, "file_vertices", 0) or len(mesh.V))
    index = getattr(mesh, "file_index", None)
    if index is None:
        index = np.arange(len(mesh.V))
    if len(values) == n_file:
        return values[np.asarray(index)]
    if len(values) == len(mesh.V):  # e.g. an STL: one value per distinct (welded) vertex
        return values
    other = f" ({len(mesh.V)} after merging coincident ones)" if len(mesh.V) != n_file else ""
    raise InputError(f"--time-file {path}: {len(values)} values, but the input mesh "
                     f"{getattr(mesh, 'path', '') or ''} has {n_file} vertices{other}",
                     fix="give one time per vertex of the input mesh, in its file order")


def resolve_time(time, V_stencil, *, default=None, source_mesh=None) -> tuple[np.ndarray, str]:
    """Turn the ``time`` option into per-stencil-vertex times.

    Parameters
    ----------
    time : None, float, str or array
        See the module docstring.
    V_stencil : (n, 3) float, mm
        Stencil target vertices (scaled, centred).
    default : callable(V) -> (n,) or None
        Shape default.
    source_mesh : object with ``V``, ``F``, ``vertex_attributes`` (dict), ``colors`` or None
        The (centred, scaled) input mesh, for per-vertex sources.

    Returns
    -------
    t : (n,) float, s
    description : str
    """
    V = np.asarray(V_stencil, float)
    n = len(V)
    if time is None:
        if default is not None:
            return validate_time(default(V), n, "default time landscape"), "shape default"
        return np.full(n, DEFAULT_TIME_S), f"constant {DEFAULT_TIME_S:g} s"
    if isinstance(time, (int, float, np.floating, np.integer)) and not isinstance(time, bool):
        return validate_time(np.full(n, float(time)), n), f"constant {float(time):g} s"
    if isinstance(time, str):
        s = time.strip()
        try:
            const = float(s)
        except ValueError:
            const = None
        if const is not None:  # (validated outside the try: InputError is a ValueError)
            return validate_time(np.full(n, const), n, f"time {s!r}"), f"constant {const:g} s"
        if s.startswith("vertex") or s.startswith("color"):
            if source_mesh is None:
                raise InputError(f"time={s!r} needs an input mesh with per-vertex data",
                                 fix="use a PLY/OBJ input with a vertex property or colours")
            vals = _vertex_source(s, source_mesh)
            t = interpolate_to_stencil(vals, source_mesh.V, source_mesh.F, V)
            return validate_time(t, n, f"time={s!r}"), s
        t = evaluate_expression(s, V)
        return validate_time(t, n, f"time expression {s!r}"), f"expression {s}"
    arr = np.asarray(time, dtype=float).ravel()
    if len(arr) == n:
        return validate_time(arr, n, "time array"), "array per stencil vertex"
    if source_mesh is not None and len(arr) == len(source_mesh.V):
        validate_time(arr, len(arr), "time array (input mesh)")
        t = interpolate_to_stencil(arr, source_mesh.V, source_mesh.F, V)
        return validate_time(t, n), "array per input vertex (interpolated)"
    raise InputError(f"time array has {len(arr)} values; the stencil has {n} vertices"
                     + (f" and the input mesh {len(source_mesh.V)}" if source_mesh else ""),
                     fix="give one value per stencil or input-mesh vertex")


@dataclass
class DesignLandscape:
    """The time landscape of a design, resolved once from the options, in one frame.

    Built once per design (:meth:`from_options`: ``--time``, ``--time-file``, the automatic
    sequencing of a mesh given no times, or the built-in shape's default) and evaluated at
    points of the **stencil frame**: the target's coordinates shifted by ``-centre`` and
    scaled by ``scale`` (``stencil.obj`` v: centred, mm).  Expressions of ``x, y, z`` see
    that frame; a built-in default, a function of the target's own coordinates, sees the
    points mapped back (``X / scale + centre``); per-vertex values of the input mesh are
    carried by the mesh moved into the frame.  Before remeshing, the design evaluates it on
    the target itself (``centre`` = the target's centroid, ``scale`` 1: the count search
    keeps the stencil's 3D scaling within a few per cent of 1), after layout on the stencil
    (``centre`` = its centroid, ``scale`` = its 3D scaling).

    Attributes
    ----------
    time : None, float, str or array
        The ``time`` source of :func:`resolve_time` (a ``--time-file`` becomes a vertex
        attribute of the input mesh, or an array for a finished stencil).
    default : callable((k, 3) float, mm) -> (k,) float, s, or None
        The built-in shape's landscape, of points in the target's own frame.
    mesh : InputMesh or None
        The input mesh (target frame), for per-vertex sources.
    description : str or None
        What the landscape is, when the source says more than :func:`resolve_time`
        (a time file, the automatic sequencing).
    time_file : dict or None
        ``--time-file`` record for ``design.json``: ``path``, ``sha256``, ``values``,
        ``carried``.
    sequencing : dict or None
        The automatic sequencing record (:func:`pysolver.design.sequencing.
        sequencing_landscape`), or None.
    given : bool
        The user gave the landscape (``--time`` or ``--time-file``).
    """

    time: object = None
    default: Callable | None = None
    mesh: object = None
    description: str | None = None
    time_file: dict | None = None
    sequencing: dict | None = None
    given: bool = False

    @classmethod
    def from_options(cls, time, time_file, *, default, mesh, name: str, stencil_input: bool):
        """Resolve the landscape options of a design (once, before any stage runs).

        Parameters
        ----------
        time : None, float, str or array
            ``--time`` (:func:`check_time_option` has checked it).
        time_file : str or Path or None
            ``--time-file``: one time per input-mesh vertex (:func:`read_time_file`).
        default : callable or None
            The built-in shape's landscape (``Surface.time``).
        mesh : InputMesh or None
            The loaded input mesh (None for a built-in shape).
        name : str
            The shape's name, for messages.
        stencil_input : bool
            The input is a finished stencil (its vertices are the stencil's).

        Raises
        ------
        InputError
            A time file for a built-in shape, or of the wrong length; a per-vertex source
            that the input does not have.
        """
        land = cls(time=time, default=default, mesh=mesh,
                   given=time is not None or time_file is not None)
        if time_file is not None:
            land._carry_time_file(time_file, name, stencil_input)
        check_time_source(land.time, mesh)
        if land.time is None and default is None and mesh is not None:
            land.time, land.sequencing = sequencing_landscape(mesh.V, mesh.F)
            if land.time is not None:
                land.description = land.sequencing["description"]
        return land

    def _carry_time_file(self, path, name: str, stencil_input: bool) -> None:
        """``--time-file`` as the landscape source: the values as they are (an array per
        stencil vertex) for a finished stencil, else a vertex attribute of the input mesh
        that :func:`resolve_time` interpolates (``vertex:<name>``)."""
        values, sha = read_time_file(path)
        if self.mesh is None:
            raise InputError(f"--time-file {path} gives values per vertex of an input mesh; "
                             f"{name} is a built-in shape",
                             fix="give the time landscape of a built-in shape with --time "
                                 "(an expression of x, y, z in mm), or design a mesh file")
        t = time_file_per_vertex(values, self.mesh, str(path))
        info = {"path": str(path), "sha256": sha, "values": int(len(values))}
        if stencil_input:  # the stencil is the input: vertex-aligned
            info["carried"] = "used as given: the input is the stencil"
            self.time = t
        else:
            self.mesh.vertex_attributes = dict(self.mesh.vertex_attributes or {},
                                               **{TIME_FILE_ATTRIBUTE: t})
            info["carried"] = "barycentric interpolation on the input surface"
            self.time = f"vertex:{TIME_FILE_ATTRIBUTE}"
        self.time_file = info
        self.description = f"--time-file {info['path']}, {info['carried']}"

    def at(self, X, centre, scale: float = 1.0) -> tuple[np.ndarray, str]:
        """The landscape at points of the stencil frame.

        Parameters
        ----------
        X : (k, 3) float, mm
            Points in the frame: target coordinates shifted by ``-centre``, times ``scale``.
        centre : (3,) float, mm
            Where the frame's origin lies in the target's own coordinates.
        scale : float
            The frame's scale over the target's.

        Returns
        -------
        t : (k,) float, s
        description : str
        """
        if self.time is None and self.default is not None:
            t, _ = resolve_time(None, X, default=lambda P: self.default(P / scale + centre))
            return t, "shape default"
        src = None if self.mesh is None else self.mesh.transformed(-centre, scale)
        t, desc = resolve_time(self.time, X, source_mesh=src)
        return t, self.description or desc

    def on_target(self, V) -> np.ndarray | None:
        """(n,) float, s, or None: the landscape at the target's own vertices ``V`` (the frame
        centred on the target, scale 1), before remeshing, so that the stencil optimisation
        can suit the cells' speeds to it; None when it is constant (programming then picks
        the constant itself).  The final landscape sees the stencil, centred on itself and
        scaled by the 3D rule (which the count search keeps within a few per cent of 1): an
        expression of x, y, z differs by that much, which the optimisation's estimate (error
        about 25 % in time) does not feel."""
        c = np.asarray(V, float).mean(axis=0)
        t, _ = self.at(V - c, c)
        return t if np.ptp(t) > TOL.time else None


def check_time_source(time, source_mesh) -> None:
    """Fail early (before remeshing) when ``time`` asks for per-vertex data that the input
    does not have."""
    if isinstance(time, str) and time.strip().startswith(("vertex", "color")):
        if source_mesh is None:
            raise InputError(f"time={time!r} needs an input mesh with per-vertex data",
                             fix="use a PLY/OBJ input with a vertex property or colours")
        _vertex_source(time.strip(), source_mesh)


def _vertex_source(spec: str, mesh) -> np.ndarray:
    attrs = getattr(mesh, "vertex_attributes", {}) or {}
    if spec.startswith("vertex"):
        name = spec.split(":", 1)[1] if ":" in spec else None
        if name is None:
            for cand in ("time_s", "time", "quality", "scalar", "value"):
                if cand in attrs:
                    name = cand
                    break
        if name is None or name not in attrs:
            raise InputError(f"time={spec!r}: the input mesh has no vertex property "
                             f"{name or '(time_s/time/quality)'!r}; it has {sorted(attrs)}",
                             fix="name the property: time='vertex:<name>'")
        return np.asarray(attrs[name], float).ravel()
    parts = spec.split(":")
    if len(parts) != 3:
        raise InputError(f"time={spec!r}: expected 'color:<t0>:<t1>' (seconds)")
    try:
        t0, t1 = float(parts[1]), float(parts[2])
    except ValueError:
        raise InputError(f"time={spec!r}: t0 and t1 must be numbers") from None
    col = getattr(mesh, "colors", None)
    if col is None:
        raise InputError(f"time={spec!r}: the input mesh has no vertex colours",
                         fix="export the mesh with vertex colours (PLY or OBJ)")
    col = np.asarray(col, float)
    if col.max() > 1.0:
        col = col / 255.0
    lum = 0.2126 * col[:, 0] + 0.7152 * col[:, 1] + 0.0722 * col[:, 2]
    return t0 + (t1 - t0) * lum


def write_landscape(folder, t_vertex) -> Path:
    """The one writer of ``time_landscape.csv``: the requested completion time per stencil
    vertex.  The design stage writes it; later, temporal programming when it maps a shape's
    default landscape onto the achievable times (``fit_landscape``), and a studio run
    (:func:`pysolver.build.rebuild`) with the user's edited landscape.

    Parameters
    ----------
    folder : path-like
        Design folder.
    t_vertex : (n_vertices,) float, s

    Returns
    -------
    Path of ``time_landscape.csv``.
    """
    t_vertex = np.asarray(t_vertex, float)
    return tables.write_table(Path(folder) / tables.FILENAMES["time_landscape"],
                              "time_landscape",
                              {"vertex_id": np.arange(len(t_vertex)), "time_s": t_vertex})


def cell_target_times(t_vertex, vertex_a, vertex_b) -> np.ndarray:
    """``t*`` per cell: mean of the landscape at the two ends of the stencil edge (s).

    The project's one definition (design, temporal programming, studio).

    Parameters
    ----------
    t_vertex : (n_vertices,) float, s
    vertex_a, vertex_b : (n_cells,) int

    Returns
    -------
    (n_cells,) float, s
    """
    t = np.asarray(t_vertex, float)
    a, b = np.asarray(vertex_a, int), np.asarray(vertex_b, int)
    if len(a) and (min(a.min(), b.min()) < 0 or max(a.max(), b.max()) >= len(t)):
        raise InputError(f"cell vertices reference {max(a.max(), b.max())} but the time "
                         f"landscape has {len(t)} vertices.",
                         fix="re-run the design stage so time_landscape.csv matches the stencil.")
    return 0.5 * (t[a] + t[b])


__all__ = ["DEFAULT_TIME_S", "TIME_FILE_ATTRIBUTE", "read_time_file", "time_file_per_vertex",
           "check_time_source", "check_time_option", "parse_expression",
           "evaluate_expression",
           "interpolate_to_stencil", "validate_time", "resolve_time",
           "cell_target_times", "DesignLandscape", "write_landscape"]
