"""Read and write the design folder's tables (``docs/design-folder.md``), with validation.

Every stage reads tables through this module.  Tables are CSV with a header row,
fixed column order, ``%.9g`` floats, ``\\n`` line ends.  Readers check the header,
every value's type and range, and raise :class:`~pysolver.errors.InputError`
naming the file, line, column and value.

Main entry points
-----------------
* :func:`write_table` / :func:`read_table` -- one table by kind
  (``"bases"``, ``"cells"``, ``"bumpers"``, ``"time_landscape"``, ``"support_frame"``).
* :func:`write_stencil` / :func:`read_stencil` -- ``stencil.obj`` (v, vt row-aligned, f).
* :func:`read_design` -- the whole folder as a :class:`Design`, cross-checked.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .core.inputs import check_input_file, read_input
from .core.writes import atomic_file, atomic_write_text
from .errors import InputError, refuse_first
from .geometry import unit_cells
from .params import UNIT_CELL, check_unit_cell
from .params import tol as TOL

# column -> type: "int", "float", "bool" (0/1), or a tuple of allowed strings
SCHEMAS: dict[str, dict[str, object]] = {
    "bases": {
        "base_id": "int", "v0": "int", "v1": "int", "v2": "int",
        "flat_x_mm": "float", "flat_y_mm": "float",
        "target_x_mm": "float", "target_y_mm": "float", "target_z_mm": "float",
        "normal_x": "float", "normal_y": "float", "normal_z": "float",
        "rot_x_rad": "float", "rot_y_rad": "float", "rot_z_rad": "float",
        "ref_slot": "int", "boundary": "bool", "alignment": "bool",
    },
    "cells": {
        "cell_id": "int", "base_a": "int", "base_b": "int", "slot_a": "int", "slot_b": "int",
        "vertex_a": "int", "vertex_b": "int", "boundary": "bool",
        "central_length_mm": "float", "bracket_length_mm": "float",
        "target_length_mm": "float", "fold_angle_deg": "float",
        "collision_length_top_mm": "float", "collision_length_bottom_mm": "float",
        "t_star_s": "float", "thickness_top_mm": "float", "thickness_bottom_mm": "float",
        "t_min_s": "float", "t_max_s": "float", "clamped": "bool",
    },
    "bumpers": {
        "base_id": "int", "layer": ("top", "bottom"), "slot": "int", "cell_id": "int",
        "neighbour": "int", "dir_deg": "float",
        "plane_px": "float", "plane_py": "float", "plane_pz": "float",
        "plane_nx": "float", "plane_ny": "float", "plane_nz": "float",
        "cut": ("bisector", "straight"), "length_mm": "float",
    },
    "time_landscape": {"vertex_id": "int", "time_s": "float"},
    "support_frame": {"x_mm": "float", "y_mm": "float"},
}

FILENAMES = {
    "bases": "bases.csv", "cells": "cells.csv", "bumpers": "bumpers.csv",
    "time_landscape": "time_landscape.csv", "support_frame": "support_frame.csv",
}

# float columns allowed to hold NaN ("not computed yet" before the temporal stage)
NAN_OK = {("cells", "t_min_s"), ("cells", "t_max_s")}
# columns whose values must be >= 0
NONNEGATIVE = {("cells", "central_length_mm"), ("cells", "target_length_mm"),
               ("cells", "collision_length_top_mm"), ("cells", "collision_length_bottom_mm"),
               ("cells", "t_star_s"), ("cells", "thickness_top_mm"),
               ("cells", "thickness_bottom_mm"), ("time_landscape", "time_s"),
               ("bumpers", "length_mm")}
SLOT_COLUMNS = {("bases", "ref_slot"), ("cells", "slot_a"), ("cells", "slot_b"),
                ("bumpers", "slot")}


def _fmt(x, kind) -> str:
    if kind == "float":
        x = float(x)
        if math.isnan(x):
            return "nan"
        return "%.9g" % (x + 0.0)  # + 0.0 turns -0.0 into 0
    if kind in ("int", "bool"):
        return str(int(x))
    return str(x)


def write_table(path, kind: str, data: dict) -> Path:
    """Write one table.

    Parameters
    ----------
    path : str or Path
        File path, or a design folder (then the standard file name is used).
    kind : str
        Key of :data:`SCHEMAS`.
    data : dict of (r,) arrays
        One array per column (all columns of the schema, same length).

    Returns
    -------
    Path of the written file.
    """
    schema = SCHEMAS[kind]
    path = Path(path)
    if path.is_dir():
        path = path / FILENAMES[kind]
    missing = [c for c in schema if c not in data]
    if missing:
        raise InputError(f"write_table({kind}): missing column(s) {missing}")
    cols = [np.asarray(data[c]) for c in schema]
    n = len(cols[0])
    for c, a in zip(schema, cols, strict=True):
        if len(a) != n:
            raise InputError(f"write_table({kind}): column {c} has {len(a)} rows, expected {n}")
    lines = [",".join(schema)]
    kinds = list(schema.values())
    for r in range(n):
        lines.append(",".join(_fmt(cols[k][r], kinds[k]) for k in range(len(kinds))))
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path


def read_table(path, kind: str) -> dict[str, np.ndarray]:
    """Read and validate one table.

    Parameters
    ----------
    path : str or Path
        File path, or a design folder.
    kind : str
        Key of :data:`SCHEMAS`.

    Returns
    -------
    dict of column name -> (r,) array (int64, float64, bool or str).
    """
    schema = SCHEMAS[kind]
    path = Path(path)
    if path.is_dir():
        path = path / FILENAMES[kind]
    rows = _table_rows(path, kind)
    expected = list(schema)
    out = {c: [] for c in expected}
    kinds = list(schema.values())
    for ln, row in enumerate(rows[1:], start=2):
        fields = row.split(",")
        if len(fields) != len(expected):
            raise InputError(f"{path}:{ln}: {len(fields)} fields, expected {len(expected)}",
                             fix="check for missing or extra commas")
        for c, k, v in zip(expected, kinds, fields, strict=True):
            v = v.strip()
            out[c].append(_value(v, k, kind, c, f"{path}:{ln}: column {c} = {v!r}"))
    dtypes = {"float": float, "int": np.int64, "bool": bool}
    res = {c: np.array(out[c], dtype=dtypes.get(k, str))
           for c, k in zip(expected, kinds, strict=True)}
    for idc in {"bases": "base_id", "cells": "cell_id",
                "time_landscape": "vertex_id"}.get(kind, "").split():
        ids = res[idc]
        bad = np.flatnonzero(ids != np.arange(len(ids)))
        if len(bad):
            raise InputError(f"{path}:{bad[0] + 2}: {idc} = {ids[bad[0]]}, expected {bad[0]} "
                             "(ids must be 0, 1, 2, ... in row order)")
    return res


def _table_rows(path: Path, kind: str) -> list[str]:
    """The non-blank lines of a table file, its header checked against the schema."""
    schema = SCHEMAS[kind]
    if not path.exists():
        where = (f"{path.parent}: no such design folder" if not path.parent.exists()
                 else f"{path}: file not found")
        raise InputError(where, fix="run the design stage first (morphshell design <shape>)")
    check_input_file(path, f"{kind} table")
    try:
        with open(path) as fh:
            text = fh.read()
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text (CSV) file",
                         fix="re-run the stage that writes it") from None
    rows = [ln for ln in text.split("\n") if ln.strip() != ""]
    if not rows:
        raise InputError(f"{path}: empty file, expected header {','.join(schema)}",
                         fix="re-run the design stage")
    header = [h.strip() for h in rows[0].split(",")]
    expected = list(schema)
    if header != expected:
        miss = [c for c in expected if c not in header]
        extra = [c for c in header if c not in expected]
        raise InputError(
            f"{path}: header does not match the {kind} table"
            + (f"; missing {miss}" if miss else "") + (f"; unexpected {extra}" if extra else "")
            + ("; columns out of order" if not miss and not extra else ""),
            fix=f"the header must be exactly: {','.join(expected)}")
    return rows


def _value(v: str, k, kind: str, c: str, where: str):
    """One field of a table, parsed as its column's type and checked (``where`` names it)."""
    if k == "float":
        try:
            x = float(v)
        except ValueError:
            raise InputError(f"{where} is not a number") from None
        if math.isnan(x) and (kind, c) not in NAN_OK:
            raise InputError(f"{where}: NaN not allowed here")
        if math.isinf(x):
            raise InputError(f"{where}: infinite value")
        if (kind, c) in NONNEGATIVE and x < 0:
            raise InputError(f"{where}: must be >= 0")
        return x
    if k in ("int", "bool"):
        try:
            x = int(v)
        except ValueError:
            raise InputError(f"{where} is not an integer") from None
        if k == "bool" and x not in (0, 1):
            raise InputError(f"{where}: must be 0 or 1")
        if (kind, c) in SLOT_COLUMNS and not 0 <= x <= 2:
            raise InputError(f"{where}: a slot must be 0, 1 or 2")
        return x
    if v not in k:
        raise InputError(f"{where}: must be one of {list(k)}")
    return v


def read_bases(path) -> dict[str, np.ndarray]:
    """``read_table(path, "bases")``."""
    return read_table(path, "bases")


def read_cells(path) -> dict[str, np.ndarray]:
    """``read_table(path, "cells")``."""
    return read_table(path, "cells")


def read_bumpers(path) -> dict[str, np.ndarray]:
    """``read_table(path, "bumpers")``."""
    return read_table(path, "bumpers")


def read_time_landscape(path) -> np.ndarray:
    """(n,) float, s: ``time_s`` of ``time_landscape.csv``."""
    return read_table(path, "time_landscape")["time_s"]


def read_support_frame(path) -> np.ndarray:
    """(b, 2) float, mm: the support-frame outline."""
    t = read_table(path, "support_frame")
    return np.c_[t["x_mm"], t["y_mm"]]


LATER_CELL_COLUMNS = ("t_star_s", "thickness_top_mm", "thickness_bottom_mm", "t_min_s",
                      "t_max_s", "clamped")
"""The columns of ``cells.csv`` that stages after the design set (temporal programming and
the refinement, through :func:`update_cells`); the design stage writes every other column,
once."""


def update_cells(folder, cells: dict, **columns) -> Path:
    """The one writer of ``cells.csv`` after the design stage: the table as read, with the
    given later-stage columns (:data:`LATER_CELL_COLUMNS`) replaced.

    Parameters
    ----------
    folder : path-like
        Design folder.
    cells : dict of (n_cells,) arrays
        ``cells.csv`` as read (:func:`read_table`); not changed.
    **columns : (n_cells,) arrays
        New values, by column name.

    Returns
    -------
    Path of ``cells.csv``.

    Raises
    ------
    InputError
        A column the design stage owns, an unknown one, or one of the wrong length.
    """
    bad = sorted(set(columns) - set(LATER_CELL_COLUMNS))
    if bad:
        raise InputError(f"update_cells: {bad} are not columns a later stage sets",
                         fix=f"set only {', '.join(LATER_CELL_COLUMNS)}; re-run the design "
                             "stage to change the others")
    n = len(cells["cell_id"])
    for k, v in columns.items():
        if len(v) != n:
            raise InputError(f"update_cells: {k} has {len(v)} values for {n} cells")
    return write_table(Path(folder) / FILENAMES["cells"], "cells", {**cells, **columns})


# --------------------------------------------------------------------------------------
# stencil.obj


STENCIL_MARKER = "# morphshell stencil"
"""First line of every ``stencil.obj`` morphshell writes: such an OBJ is read as a stencil
(:func:`pysolver.design.mesh_input.load_input`); any other OBJ only with ``--stencil``."""


def write_stencil(path, V, UV, F) -> Path:
    """Write ``stencil.obj``: ``v`` (target, mm), ``vt`` (flat, mm, row-aligned), ``f`` 1-based."""
    V = np.asarray(V, float)
    UV = np.asarray(UV, float)
    F = np.asarray(F, dtype=np.int64)
    _check_stencil(V, UV, F, str(path))
    path = Path(path)
    if path.is_dir():
        path = path / "stencil.obj"
    lines = [f"{STENCIL_MARKER}: v = target (mm), vt = flat layout (mm), row-aligned"]
    lines += ["v {:.9g} {:.9g} {:.9g}".format(*tuple(p)) for p in V + 0.0]
    lines += ["vt {:.9g} {:.9g}".format(*tuple(p)) for p in UV + 0.0]
    lines += ["f {} {} {}".format(*(f + 1)) for f in F]
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path


def round_sig9(X) -> np.ndarray:
    """Round values to 9 significant digits, exactly as the writers format them
    (so tables computed from the result agree with what ``stencil.obj`` stores)."""
    X = np.asarray(X, float)
    return np.array([float(f"{v:.9g}") for v in X.ravel()]).reshape(X.shape)


def _check_stencil(V, UV, F, where):
    if V.ndim != 2 or V.shape[1] != 3 or len(V) < 3:
        raise InputError(f"{where}: need at least 3 vertices with 3 coordinates, got {V.shape}")
    if UV.shape != (len(V), 2):
        raise InputError(f"{where}: {len(UV)} flat (vt) vertices for {len(V)} target (v) "
                         "vertices; they must be row-aligned",
                         fix="give one vt per v, in the same order")
    if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
        raise InputError(f"{where}: faces must be triangles, got shape {F.shape}",
                         fix="triangulate the mesh")
    if F.min() < 0 or F.max() >= len(V):
        raise InputError(f"{where}: face index out of range (0..{len(V) - 1}): "
                         f"{F.min()}..{F.max()}")
    if not (np.all(np.isfinite(V)) and np.all(np.isfinite(UV))):
        raise InputError(f"{where}: NaN or infinite coordinates")


def read_stencil(path):
    """Read a stencil OBJ.

    ``f`` may use plain indices (vt row-aligned with v) or ``v/vt`` pairs; with pairs
    the vt indices must map one-to-one onto the v indices (no seams), and vt is
    reordered to be row-aligned.  Faces with more than 3 corners are refused.

    Returns
    -------
    V : (n, 3) float
    UV : (n, 2) float or None
        None if the file has no vt.
    F : (m, 3) int
    """
    path = Path(path)
    if path.is_dir():
        path = path / "stencil.obj"
    if not path.exists():
        raise InputError(f"{path}: file not found",
                         fix="run the design stage first (morphshell design <shape>)")
    check_input_file(path, "stencil")
    V, T, F, FT = _obj_records(path)
    if not V or not F:
        raise InputError(f"{path}: no vertices or no faces", fix="check the OBJ file")
    V = np.array(V, float)
    F = np.array(F, dtype=np.int64)
    F = np.where(F < 0, F + len(V), F - 1)  # OBJ negative = relative
    UV = _row_aligned_uv(path, V, F, T, FT) if T else None
    _check_stencil(V, UV if UV is not None else np.zeros((len(V), 2)), F, str(path))
    return V, UV, F


def _obj_records(path: Path):
    """The ``v``, ``vt``, ``f`` (vertex indices) and ``f`` (vt indices, when every corner
    gives one) records of an OBJ, as lists; faces must be triangles."""
    V, T, F, FT = [], [], [], []
    with open(path, errors="replace") as fh:
        for ln, line in enumerate(fh, start=1):
            parts = line.split()
            if not parts or parts[0].startswith("#"):
                continue
            tag = parts[0]
            try:
                if tag == "v":
                    V.append([float(x) for x in parts[1:4]])
                    if len(V[-1]) != 3:
                        raise ValueError
                elif tag == "vt":
                    T.append([float(x) for x in parts[1:3]])
                    if len(T[-1]) != 2:
                        raise ValueError
                elif tag == "f":
                    corners = parts[1:]
                    if len(corners) != 3:
                        raise InputError(f"{path}:{ln}: face with {len(corners)} corners",
                                         fix="triangulate the mesh")
                    idx = [c.split("/") for c in corners]
                    F.append([int(c[0]) for c in idx])
                    if all(len(c) > 1 and c[1] != "" for c in idx):
                        FT.append([int(c[1]) for c in idx])
            except InputError:
                raise
            except ValueError:
                raise InputError(f"{path}:{ln}: cannot parse {line.strip()!r}") from None
    return V, T, F, FT


def _row_aligned_uv(path: Path, V, F, T, FT) -> np.ndarray:
    """(n, 2) float: the ``vt`` of an OBJ row-aligned with its ``v``: as given (one per v), or
    through ``v/vt`` face indices, which must map one-to-one (no seam)."""
    T = np.array(T, float)
    if FT and len(FT) == len(F):
        FT = np.array(FT, dtype=np.int64)
        FT = np.where(FT < 0, FT + len(T), FT - 1)
        UV = np.full((len(V), 2), np.nan)
        mapping = {}
        for fv, ft in zip(F.ravel(), FT.ravel(), strict=True):
            if mapping.setdefault(fv, ft) != ft:
                raise InputError(
                    f"{path}: vertex {fv + 1} uses several vt ({mapping[fv] + 1}, {ft + 1}):"
                    " the flat layout has a seam", fix="give a one-to-one vt per v")
        for fv, ft in mapping.items():
            UV[fv] = T[ft]
        if np.isnan(UV).any():
            raise InputError(f"{path}: some vertices are not used by any face",
                             fix="remove unreferenced vertices")
        return UV
    if len(T) == len(V):
        return T
    raise InputError(f"{path}: {len(T)} vt for {len(V)} v and faces without vt indices",
                     fix="for a stencil, give one vt per v (row-aligned) or v/vt face "
                         "indices; for a plain target mesh, delete its vt lines (e.g. "
                         "grep -v '^vt ' in.obj > target.obj), which a mesh does not "
                         "need")


# --------------------------------------------------------------------------------------
# the whole folder


@dataclass
class Design:
    """A design folder loaded into memory.

    Attributes
    ----------
    folder : Path
    V : (n, 3) float, mm  -- target stencil vertices
    UV : (n, 2) float, mm -- flat stencil vertices
    F : (m, 3) int
    bases, cells, bumpers : dict of column arrays
    time : (n,) float, s -- time landscape per vertex
    support : (b, 2) float, mm -- flat support-frame outline
    meta : dict -- design.json
    """

    folder: Path
    V: np.ndarray
    UV: np.ndarray
    F: np.ndarray
    bases: dict
    cells: dict
    bumpers: dict
    time: np.ndarray
    support: np.ndarray
    meta: dict = field(default_factory=dict)

    @property
    def params(self):
        """The unit cell of this design (``design.json``), :func:`design_unit_cell`."""
        return design_unit_cell(self.meta, str(self.folder / "design.json"))

    @property
    def n_bases(self) -> int:
        return len(self.F)

    @property
    def n_cells(self) -> int:
        return len(self.cells["cell_id"])


def read_design(folder, check: bool = True) -> Design:
    """Load a design folder and cross-check its tables.

    Parameters
    ----------
    folder : str or Path
    check : bool
        Cross-check the tables against the stencil (ids, vertex refs, cell order).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a design folder",
                         fix="run the design stage first (morphshell design <shape>)")
    V, UV, F = read_stencil(folder / "stencil.obj")
    if UV is None:
        raise InputError(f"{folder / 'stencil.obj'}: no vt (flat layout)")
    bases = read_table(folder, "bases")
    cells = read_table(folder, "cells")
    bumpers = read_table(folder, "bumpers")
    tl = read_table(folder, "time_landscape")
    sf = read_table(folder, "support_frame")
    meta = {}
    if (folder / "design.json").exists():
        try:
            meta = json.loads(read_input(folder / "design.json", "design record"))
        except json.JSONDecodeError as e:
            raise InputError(f"{folder / 'design.json'}: invalid JSON ({e})") from None
    d = Design(folder, V, UV, F, bases, cells, bumpers, tl["time_s"],
               np.c_[sf["x_mm"], sf["y_mm"]], meta)
    if check:
        check_design(d)
    return d


def design_unit_cell(meta: dict, source="design.json"):
    """The unit cell a design was made with, from its ``design.json`` (``options.params``).

    Later stages read the design's own tolerances (``min_bumper``, ``min_gap``,
    ``max_cell_length``, set by ``--min-bumper`` etc.) from here, never the defaults.

    Parameters
    ----------
    meta : dict
        Content of ``design.json`` (``{}`` when the folder has none: the defaults).
    source : str
        File named in messages.

    Returns
    -------
    pysolver.params.UnitCell

    Raises
    ------
    InputError
        A value that is not a number, or a tolerance outside its range.
    """
    stored = ((meta or {}).get("options") or {}).get("params") or {}
    if not isinstance(stored, dict):
        raise InputError(f"{source}: options.params is not an object",
                         fix="re-run the design stage")
    known = {f.name for f in dataclasses.fields(UNIT_CELL)}
    vals = {}
    for k, v in stored.items():
        if k not in known:
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            raise InputError(f"{source}: options.params.{k} = {v!r} is not a finite number",
                             fix="re-run the design stage")
        vals[k] = float(v)
    params = dataclasses.replace(UNIT_CELL, **vals)
    try:
        check_unit_cell(params)
    except InputError as e:
        raise InputError(f"{source}: {e.problem}", fix="re-run the design stage") from None
    return params


def read_record(path) -> dict | None:
    """A JSON record of a design folder (``design.json``, ``summary.json``, ...) for display:
    its content, or ``None`` if the file is missing, unreadable or not JSON."""
    try:
        return json.loads(read_input(path, "record"))
    except (OSError, ValueError):  # (InputError is a ValueError)
        return None


PREDICTED_SD = "t_sd_predicted_s"
"""Key of each cell's predicted completion-time sd under the per-bracket thickness scatter
(s, None where a layer does not close) in ``temporal.json`` (program stage) and
``sim/refine.json`` (the refinement, for the thicknesses it kept)."""


def predicted_timing_sd(folder, n_cells: int):
    """Each cell's predicted completion-time sd (n,) s, NaN where unknown, for the
    thicknesses now in ``cells.csv``: the refinement's record when there is one (it writes
    the thicknesses last) and it is not older than the program stage's, else the program
    stage's; None when neither has it (a folder
    programmed before the key existed) or its length is not ``n_cells``."""
    folder = Path(folder)
    paths = [folder / "sim" / "refine.json", folder / "temporal.json"]
    if all(p.is_file() for p in paths) and paths[0].stat().st_mtime < paths[1].stat().st_mtime:
        paths = paths[1:]  # programmed again after the refinement: its record is stale
    for path in paths:
        sd = record_numbers((read_record(path) or {}).get(PREDICTED_SD), n_cells)
        if sd is not None:
            return sd
    return None


def record_numbers(values, n: int):
    """A per-cell list read from a JSON record as a float array (n,), ``null`` as NaN (how
    :func:`pysolver.core.records.json_text` writes a non-finite number); None when
    ``values`` is not a list of ``n`` entries that are each a number or ``null`` (a record
    is read, never trusted: a string, a bool or a nested list is not taken for a number)."""
    if not isinstance(values, list) or len(values) != n or any(
            v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)))
            for v in values):
        return None
    return np.array([np.nan if v is None else v for v in values], float)


def read_unit_cell(folder):
    """:func:`design_unit_cell` of a design folder's ``design.json`` (defaults without one)."""
    path = Path(folder) / "design.json"
    if not path.is_file():
        return design_unit_cell({})
    try:
        meta = json.loads(read_input(path, "design record"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: invalid JSON ({e})", fix="re-run the design stage") from None
    return design_unit_cell(meta, str(path))


def check_thickness(th, where: str, *, cell_ids=None, rows: bool = True,
                    programmed: bool = False, in_range: bool = True, unit=UNIT_CELL) -> None:
    """The one bracket-thickness validator (design tables, simulator, tolerance analysis).

    Parameters
    ----------
    th : (c, 2) float, mm
        Thickness per cell and layer (top, bottom); NaN = not programmed yet.
    where : str
        File (``.../cells.csv``) or model named in messages.
    cell_ids : (c,) int, optional
        Cell ids named in messages (default 0..c-1).
    rows : bool
        ``where`` is a CSV file: name the row (cell + 2) too.
    programmed : bool
        Every value must be finite and positive (the simulator's need).
    in_range : bool
        Values must lie in ``unit.thickness_min``-``unit.thickness_max`` (within
        ``tol.thickness``): printable, and inside the measured material model.

    Raises
    ------
    InputError
        Naming the file, row, cell, column and value, the rule and the fix.
    """
    th = np.asarray(th, float)
    ids = np.arange(len(th)) if cell_ids is None else np.asarray(cell_ids)
    lo, hi = unit.thickness_min, unit.thickness_max
    at = (lambda k: f"{where}:{k + 2}") if rows else (lambda k: where)
    if th.ndim != 2 or th.shape[1] != 2:
        raise InputError(f"{where}: thickness has shape {th.shape}, expected (cells, 2) "
                         "(cells x layers)", fix="pass one thickness per cell and layer")
    if programmed:
        refuse_first(~np.all(np.isfinite(th) & (th > 0), axis=1),
                     lambda k, _: f"{at(k)}: cell {int(ids[k])} has bracket thickness "
                                  f"{th[k].tolist()} mm",
                     fix="run the program (temporal) stage so every cell has a thickness in "
                         f"{lo:.2f}-{hi:.2f} mm")
    if not in_range:
        return
    for j, col in enumerate(("thickness_top_mm", "thickness_bottom_mm")):
        h = th[:, j]
        refuse_first((h < lo - TOL.thickness) | (h > hi + TOL.thickness),
                     lambda i, n, col=col, h=h:  # (the loop's values, bound now)
                         f"{at(i)} (cell {int(ids[i])}): {col} = {h[i]:g} mm is outside the "
                         f"bracket thickness range {lo}-{hi} mm ({n} cell(s) in all)",
                     fix="use thicknesses in range (thinner brackets do not print, thicker "
                         "ones are outside the material model), or re-run 'morphshell "
                         "program DIR'")


def check_design(d: Design) -> None:
    """Cross-check a loaded design; raises InputError naming the first inconsistency."""
    f = d.folder
    m, n = len(d.F), len(d.V)
    c = d.cells
    # references to bases / vertices that do not exist (hand edits), named row by row
    for col, count, what in (("base_a", m, "base"), ("base_b", m, "base"),
                             ("vertex_a", n, "stencil vertex"), ("vertex_b", n, "stencil vertex")):
        refuse_first((c[col] < 0) | (c[col] >= count),
                     lambda i, _, col=col, what=what, count=count:  # (bound now)
                         f"{f}/cells.csv:{i + 2} (cell {int(c['cell_id'][i])}): {col} = "
                         f"{int(c[col][i])} refers to a {what} that does not exist (the design "
                         f"has {count}, ids 0..{count - 1})",
                     fix="undo the hand edit of cells.csv, or re-run the design stage")
    for col, count in (("base_id", m), ("neighbour", m), ("cell_id", len(c["cell_id"]))):
        v = d.bumpers[col]
        refuse_first((v < 0) | (v >= count),
                     lambda i, _, col=col, v=v, count=count:  # (bound now)
                         f"{f}/bumpers.csv:{i + 2}: {col} = {int(v[i])} does not exist (ids "
                         f"0..{count - 1})",
                     fix="undo the hand edit of bumpers.csv, or re-run the design stage")
    # bracket thickness: printable and inside the measured material model
    check_thickness(np.c_[c["thickness_top_mm"], c["thickness_bottom_mm"]], f"{f}/cells.csv",
                    cell_ids=c["cell_id"])
    if len(d.bases["base_id"]) != m:
        raise InputError(f"{f}/bases.csv: {len(d.bases['base_id'])} rows for {m} stencil faces",
                         fix="re-run the design stage")
    Fb = np.c_[d.bases["v0"], d.bases["v1"], d.bases["v2"]]
    refuse_first(np.any(Fb != d.F, axis=1),
                 lambda i, _: f"{f}/bases.csv:{i + 2}: vertices {Fb[i].tolist()} differ from "
                              f"stencil face {d.F[i].tolist()}")
    if len(d.time) != n:
        raise InputError(f"{f}/time_landscape.csv: {len(d.time)} rows for {n} stencil vertices")
    cells = unit_cells(d.F)
    if len(cells.faces) != d.n_cells:
        raise InputError(f"{f}/cells.csv: {d.n_cells} rows but the stencil has "
                         f"{len(cells.faces)} interior edges")
    got = np.c_[d.cells["base_a"], d.cells["base_b"], d.cells["slot_a"], d.cells["slot_b"],
                d.cells["vertex_a"], d.cells["vertex_b"]]
    exp = np.c_[cells.faces, cells.slots, cells.verts]
    refuse_first(np.any(got != exp, axis=1),
                 lambda i, _: f"{f}/cells.csv:{i + 2}: (base_a, base_b, slot_a, slot_b, "
                              f"vertex_a, vertex_b) = {got[i].tolist()}, stencil gives "
                              f"{exp[i].tolist()}")
    b = d.bumpers
    if len(b["base_id"]) and (b["base_id"].max() >= m or b["cell_id"].max() >= d.n_cells):
        raise InputError(f"{f}/bumpers.csv: base_id or cell_id out of range")
    n_exp = 2 * 2 * d.n_cells
    if len(b["base_id"]) != n_exp:
        raise InputError(f"{f}/bumpers.csv: {len(b['base_id'])} rows, expected {n_exp} "
                         "(2 layers x 2 bases x cells)")


# ----------------------------------------------------------------------------------------------
# model.npz: the simulator's geometry, written by the design stage


MODEL_FILE = "model.npz"
"""The bracket nodes and unit-cell topology the simulator reads (``docs/design-folder.md``)."""

# array -> (shape in m faces, c cells, n vertices, dtype kind)
MODEL_ARRAYS: dict[str, tuple[tuple, str]] = {
    "face_adjacency": (("m", 3), "i"),
    "cell_bases": (("c", 2), "i"), "cell_slots": (("c", 2), "i"), "cell_verts": (("c", 2), "i"),
    "cell_of": (("m", 3), "i"), "cell_boundary": (("c",), "b"),
    "boundary_vertex": (("n",), "b"),
    "nodes_target": (("m", 3, 2, 2, 3), "f"), "nodes_flat": (("m", 3, 2, 2, 3), "f"),
}
_MODEL_FIX = "re-run the design stage (morphshell design ...), which writes model.npz"


def model_inputs_hash(folder, params) -> str:
    """sha256 of what ``model.npz`` is computed from: ``stencil.obj``, ``bases.csv`` and the
    unit cell (``params``, a :class:`pysolver.params.UnitCell`)."""
    folder = Path(folder)
    h = hashlib.sha256()
    for name in ("stencil.obj", FILENAMES["bases"]):
        h.update((folder / name).read_bytes())
    h.update(json.dumps(params.to_dict(), sort_keys=True).encode())
    return h.hexdigest()


TABLE_FILES = ("stencil.obj", "design.json", *FILENAMES.values())
"""The design folder's tables: what the later stages' outputs are made from."""
LANDSCAPE_SOURCE = "studio_landscape.json"
"""How the landscape of a build edited in the studio was made (the report's provenance)."""
PARTS_RECORD = "stl/parts.json"
"""Written with the STLs: the :func:`tables_sha256` of the tables they were made from and each
STL's sha256 (the report lists the STLs only while both match)."""


def tables_sha256(folder) -> str:
    """sha256 of a design folder's tables (:data:`TABLE_FILES`; a missing file counts as
    empty), recorded by every output made from them (``sim/frames.npz``, ``stl/parts.json``,
    ``report/report.json``) so that the report can tell parts or frames made from other
    tables (an edited landscape, a later ``program``) from its own."""
    folder = Path(folder)
    h = hashlib.sha256()
    for name in TABLE_FILES:
        p = folder / name
        data = p.read_bytes() if p.is_file() else b""
        h.update(f"{name}\0{len(data)}\0".encode() + data)
    return h.hexdigest()


def write_model(folder, arrays: dict, inputs_sha256: str) -> Path:
    """Write ``model.npz`` (uncompressed, fixed zip timestamps: same arrays, same bytes).

    Parameters
    ----------
    folder : path-like
        Design folder.
    arrays : dict of ndarray
        Every array of :data:`MODEL_ARRAYS`.
    inputs_sha256 : str
        :func:`model_inputs_hash` of the tables the arrays were computed from.
    """
    missing = [k for k in MODEL_ARRAYS if k not in arrays]
    if missing:
        raise InputError(f"write_model: missing array(s) {missing}")
    path = Path(folder) / MODEL_FILE
    items = [(k, np.ascontiguousarray(arrays[k])) for k in MODEL_ARRAYS]
    items.append(("inputs_sha256", np.array(inputs_sha256)))
    with atomic_file(path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED) as zf:
        for name, a in items:
            with zf.open(zipfile.ZipInfo(name + ".npy", date_time=(1980, 1, 1, 0, 0, 0)),
                         "w") as fh:
                np.lib.format.write_array(fh, a, allow_pickle=False)
    return path


def read_model(folder, *, n_vertices: int, n_faces: int, n_cells: int, params) -> dict:
    """Read and check ``model.npz`` against the design's sizes and tables.

    Returns
    -------
    dict of ndarray
        The arrays of :data:`MODEL_ARRAYS`.

    Raises
    ------
    InputError
        A missing file or array, a wrong shape, or tables edited after the design stage.
    """
    folder = Path(folder)
    path = folder / MODEL_FILE
    if not path.is_file():
        raise InputError(f"{path} does not exist (design folders from before model.npz, or a "
                         "hand-made folder)", fix=_MODEL_FIX)
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile) as e:
        raise InputError(f"{path}: unreadable ({e})", fix=_MODEL_FIX) from None
    size = {"m": n_faces, "c": n_cells, "n": n_vertices}
    for k, (shape, kind) in MODEL_ARRAYS.items():
        if k not in data:
            raise InputError(f"{path}: no array {k!r}", fix=_MODEL_FIX)
        want = tuple(size.get(d, d) for d in shape)
        if data[k].shape != want or data[k].dtype.kind != kind:
            raise InputError(f"{path}: {k} has shape {data[k].shape} ({data[k].dtype}), "
                             f"expected {want} ({kind})", fix=_MODEL_FIX)
    stored = str(data.get("inputs_sha256", ""))
    if stored != model_inputs_hash(folder, params):
        raise InputError(f"{path} was computed from another stencil.obj, bases.csv or unit "
                         "cell than the folder now holds (edited after the design stage)",
                         fix=_MODEL_FIX)
    return {k: data[k] for k in MODEL_ARRAYS}


__all__ = ["SCHEMAS", "FILENAMES", "write_table", "read_table", "read_bases", "read_cells",
           "read_bumpers", "read_time_landscape", "read_support_frame", "write_stencil",
           "read_stencil", "Design", "read_design", "check_design", "round_sig9",
           "design_unit_cell", "read_unit_cell", "read_record", "MODEL_FILE", "MODEL_ARRAYS",
           "write_model", "read_model", "model_inputs_hash", "check_thickness", "TABLE_FILES",
           "tables_sha256", "PARTS_RECORD", "LANDSCAPE_SOURCE", "PREDICTED_SD",
           "predicted_timing_sd", "record_numbers"]
