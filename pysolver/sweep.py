"""``morphshell sweep SPEC.toml``: build a grid or a list of design variants on Dask and
tabulate their key figures.

The spec (TOML, parsed with ``tomllib`` and validated key by key; nothing is evaluated)::

    name = "regular-seeds"        # optional: output folder build/sweep-<name>

    [base]                        # build options shared by every variant
    shape = "regular"             # a built-in shape, or a mesh file (relative to the spec)
    refine = 0
    t_end = 90.0

    [grid]                        # every combination of these lists (cartesian product)
    vertices = [36, 42]
    seed = [0, 1]

    [[variant]]                   # and/or explicit variants: base updated by each entry
    name = "dome-late"            # optional file-safe name
    shape = "dome"
    time = "30 + 0.5*z"

Build options (:func:`pysolver.build.build`): ``shape`` (str), ``vertices`` (int),
``seed`` (int), ``time`` (str or number: a closed time-landscape expression), ``scale``
(number), ``flattening`` ("cetm" | "lscm"), ``material`` (bracket model file), ``refine``
(int), ``program``, ``render`` (default false), ``simulate`` (default true) (bools),
``t_end``, ``dt`` (s).

Each variant is one Dask task (:mod:`pysolver.distributed`) that carries its options and
the bytes of its input files (mesh, material), so a worker on another machine needs no
shared file system.  It builds into ``<out>/builds/<variant>/`` on the machine that runs
it and returns the key figures; the caller writes each row atomically to
``<out>/results/<variant>.json`` (a rerun builds only the missing variants), then
``<out>/table.csv``, ``<out>/index.html`` and ``<out>/sweep.png``.
"""

from __future__ import annotations

import csv
import html
import io
import itertools
import math
import re
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

from .build import build
from .core.inputs import read_input
from .core.ownership import claim_result_folder
from .core.progress import say
from .core.writes import atomic_file, atomic_write_text
from .distributed import (
    ResultStore,
    Task,
    check_scheduler,
    check_workers,
    code_fingerprint,
    fingerprint,
    run_tasks,
)
from .errors import InputError, MorphshellError
from .params import TOLERANCE_RUN

BUILD_ROOT = Path("build")
OPTION_TYPES = {
    "shape": (str,), "vertices": (int,), "seed": (int,), "time": (str, int, float),
    "scale": (int, float), "flattening": (str,), "material": (str,), "refine": (int,),
    "program": (bool,), "render": (bool,), "simulate": (bool,), "t_end": (int, float),
    "dt": (int, float),
}
DEFAULTS = {"render": False, "simulate": True}
FILE_OPTIONS = ("shape", "material")
COLUMNS = ("variant", "shape", "vertices", "seed", "time", "material", "refine", "t_end",
           "exit_code", "verdict", "n_bases", "n_cells", "max_cell_length_mm",
           "clamped_fraction", "longest_cell_s", "shape_rms_pct", "shape_rms_mm",
           "timing_rms_s", "timing_spearman", "never_complete", "build_s", "error")
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,80}$")


def _check_options(opts: dict, where: str) -> dict:
    bad = sorted(set(opts) - set(OPTION_TYPES))
    if bad:
        raise InputError(f"{where}: unknown option(s) {', '.join(map(repr, bad))}",
                         fix=f"use only {', '.join(OPTION_TYPES)}")
    for k, v in opts.items():
        types = OPTION_TYPES[k]
        ok = isinstance(v, types) and not (isinstance(v, bool) and bool not in types)
        if not ok:
            kinds = " or ".join(t.__name__ for t in types)
            raise InputError(f"{where}: {k} = {v!r} is not a {kinds}",
                             fix=f"write {k} as a TOML {types[0].__name__}")
        if isinstance(v, float) and not math.isfinite(v):
            raise InputError(f"{where}: {k} = {v!r}", fix="use a finite number")
    return opts


def _auto_name(opts: dict, keys) -> str:
    parts = [str(opts.get("shape", "shape"))]
    parts[0] = Path(parts[0]).stem if "." in parts[0] else parts[0]
    for k in keys:
        v = opts[k]
        parts.append(f"{k}-{Path(v).stem if k in FILE_OPTIONS else v}")
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", "_".join(parts)).strip("._-") or "variant"
    return name[:80]


def load_spec(path) -> dict:
    """Read and validate a sweep spec.

    Parameters
    ----------
    path : path-like
        TOML file.

    Returns
    -------
    dict
        ``name`` (str), ``variants`` (list of dict: ``name`` + build options, file options
        resolved to absolute paths), ``spec_dir`` (Path).

    Raises
    ------
    InputError
        Unreadable TOML, unknown keys, wrong types, duplicate names, too many variants.
    """
    p = Path(path)
    spec = _read_toml(p)
    name = spec.get("name", p.stem)
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise InputError(f"sweep spec {p}: name = {name!r}",
                         fix="use letters, digits, '_', '.', '-'")
    base = spec.get("base", {})
    grid = spec.get("grid", {})
    explicit = spec.get("variant", [])
    if not isinstance(base, dict) or not isinstance(grid, dict) or not isinstance(explicit,
                                                                                 list):
        raise InputError(f"sweep spec {p}: [base] and [grid] must be tables, [[variant]] an "
                         "array of tables", fix="see the example in docs/tolerance.md")
    _check_options(base, f"{p} [base]")
    for k, vals in grid.items():
        if not isinstance(vals, list) or not vals:
            raise InputError(f"{p} [grid]: {k} must be a non-empty list",
                             fix=f"e.g. {k} = [1, 2]")
        for v in vals:
            _check_options({k: v}, f"{p} [grid]")
    n_grid = math.prod(len(v) for v in grid.values()) if grid else 0
    if n_grid + len(explicit) > TOLERANCE_RUN.max_variants:
        raise InputError(f"sweep spec {p}: {n_grid + len(explicit)} variants",
                         fix=f"at most {TOLERANCE_RUN.max_variants} per sweep")
    variants = _grid_variants(base, grid) + _listed_variants(base, explicit, p)
    if not variants:
        variants = [dict(base, name=_auto_name(base, []))]
    _check_variants(variants, p)
    return {"name": name, "variants": variants, "spec_dir": p.parent.absolute()}


def _read_toml(p: Path) -> dict:
    """The spec's TOML with only the known top-level keys."""
    try:
        spec = tomllib.loads(read_input(p, "sweep spec").decode("utf-8"))
    except OSError as e:
        raise InputError(f"sweep spec {p}: {e.strerror}", fix="give an existing TOML file") \
            from None
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise InputError(f"sweep spec {p}: not valid TOML ({e})",
                         fix="see the example in docs/tolerance.md") from None
    unknown = sorted(set(spec) - {"name", "base", "grid", "variant"})
    if unknown:
        raise InputError(f"sweep spec {p}: unknown key(s) {', '.join(map(repr, unknown))}",
                         fix="use name, [base], [grid] and [[variant]]")
    return spec


def _grid_variants(base: dict, grid: dict) -> list:
    """Every combination of the grid's values on top of the base options."""
    keys = list(grid)
    out = []
    for combo in itertools.product(*(grid[k] for k in keys)) if grid else ():
        o = dict(base, **dict(zip(keys, combo, strict=True)))
        out.append(dict(o, name=_auto_name(o, keys)))
    return out


def _listed_variants(base: dict, explicit: list, p: Path) -> list:
    """The ``[[variant]]`` entries on top of the base options (checked, named)."""
    out = []
    for i, v in enumerate(explicit):
        if not isinstance(v, dict):
            raise InputError(f"{p} [[variant]] {i + 1}: not a table")
        v = dict(v)
        vname = v.pop("name", None)
        _check_options(v, f"{p} [[variant]] {i + 1}")
        o = dict(base, **v)
        if vname is None:
            vname = _auto_name(o, sorted(v))
        if not isinstance(vname, str) or not NAME_RE.match(vname):
            raise InputError(f"{p} [[variant]] {i + 1}: name = {vname!r}",
                             fix="use letters, digits, '_', '.', '-'")
        out.append(dict(o, name=vname))
    return out


def _check_variants(variants: list, p: Path) -> None:
    """Distinct names, a shape each, and the file options resolved to existing files
    (relative to the spec's folder; changed in place)."""
    names = [v["name"] for v in variants]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"sweep spec {p}: duplicate variant name(s) {dup}",
                         fix="give the [[variant]] entries distinct names")
    for v in variants:
        if "shape" not in v:
            raise InputError(f"sweep spec {p}: variant {v['name']} has no shape",
                             fix="set shape in [base] or in the variant")
        for k in FILE_OPTIONS:
            if k in v and (k != "shape" or _is_file_like(v[k])):
                f = (p.parent / v[k]).absolute()
                if not f.is_file():
                    raise InputError(f"sweep spec {p}: variant {v['name']}: {k} file {f} "
                                     "does not exist",
                                     fix="paths are relative to the spec file's folder")
                v[k] = str(f)


def _is_file_like(shape: str) -> bool:
    return "/" in shape or "." in shape


def build_variant(opts: dict, files: dict, out: str) -> dict:
    """Build one variant and return its table row (the Dask task).

    Parameters
    ----------
    opts : dict
        Build options; file options name keys of ``files``.
    files : dict of str -> (str, bytes)
        Option -> (file name, content) of the input files.
    out : str
        Build folder on the worker.

    Returns
    -------
    dict
        One row of :data:`COLUMNS`.
    """
    t0 = time.perf_counter()
    kw = {k: v for k, v in opts.items() if k != "name"}
    for k, v in DEFAULTS.items():
        kw.setdefault(k, v)
    row = {"variant": opts["name"]}
    with tempfile.TemporaryDirectory(prefix="morphshell-sweep-") as tmp:
        for k, (fname, data) in files.items():
            f = Path(tmp) / k / fname
            f.parent.mkdir()
            f.write_bytes(data)
            kw[k] = str(f)
        try:
            summary = build(kw.pop("shape"), out=out, progress=False, **kw)
            row.update(figures_row(summary))
        except MorphshellError as e:  # a variant that cannot be built is a row, not a crash
            row.update({"exit_code": e.exit_code, "verdict": "ERROR",
                        "error": str(e).splitlines()[0][:300]})
    row["build_s"] = round(time.perf_counter() - t0, 3)
    return row


def figures_row(summary: dict) -> dict:
    """Key figures of a build's ``summary.json`` (and its report) as one table row."""
    st = summary.get("stages", {})
    fig = summary.get("figures", {})
    rep = st.get("report", {}).get("metrics", {})
    sim = st.get("simulate", {})
    prog = st.get("program", {})
    tm, sh = rep.get("timing", {}), rep.get("shape", {})
    return {"exit_code": summary.get("exit_code", 0), "verdict": fig.get("verdict"),
            "n_bases": fig.get("n_bases"), "n_cells": fig.get("n_cells"),
            "max_cell_length_mm": fig.get("max_central_length_mm"),
            "clamped_fraction": prog.get("fraction_clamped"),
            "longest_cell_s": sim.get("completion_time_max_s"),
            "shape_rms_pct": sh.get("rms_pct"), "shape_rms_mm": sh.get("rms_mm"),
            "timing_rms_s": tm.get("rms_s"), "timing_spearman": tm.get("spearman"),
            "never_complete": tm.get("n_never"), "error": ""}


def _cell(v):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, float):
        return f"{v:.9g}"
    return str(v)


def write_table(out: Path, rows: list, title: str) -> None:
    """``table.csv``, ``sweep.png`` and ``index.html`` of the rows."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for r in rows:
        w.writerow([_cell(r.get(c)) for c in COLUMNS])
    atomic_write_text(out / "table.csv", buf.getvalue())
    _plot(out / "sweep.png", rows)
    head = "".join(f"<th>{html.escape(c)}</th>" for c in COLUMNS)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(_cell(r.get(c)))}</td>"
                                    for c in COLUMNS) + "</tr>" for r in rows)
    counts = {v: sum(r.get("verdict") == v for r in rows)
              for v in ("PASS", "WARN", "FAIL", "ERROR")}
    page = (f"<!doctype html><html lang='en'><head><meta charset='utf-8'><title>morphshell "
            f"sweep {html.escape(title)}</title><style>body{{font-family:sans-serif;margin:1em}}"
            "table{border-collapse:collapse;font-size:90%}td,th{border:1px solid #ccc;"
            "padding:2px 6px;text-align:right}th{background:#eee}img{max-width:100%}</style>"
            f"</head><body><h1>Sweep {html.escape(title)}</h1><p>{len(rows)} variants: "
            + ", ".join(f"{k} {v}" for k, v in counts.items()) + ". Data: "
            "<a href='table.csv'>table.csv</a>.</p><img src='sweep.png' alt='figures'>"
            f"<table><tr>{head}</tr>{body}</table></body></html>\n")
    atomic_write_text(out / "index.html", page)


def _plot(path: Path, rows: list) -> None:
    import matplotlib  # optional heavy dependency: matplotlib loads only when a picture is drawn

    matplotlib.use("Agg")
    # optional heavy dependency: matplotlib loads only when a picture is drawn
    import matplotlib.pyplot as plt


    names = [r["variant"] for r in rows]
    y = np.arange(len(rows))
    colors = {"PASS": "tab:green", "WARN": "tab:orange", "FAIL": "tab:red"}
    c = [colors.get(r.get("verdict"), "0.5") for r in rows]

    def col(k):
        return [np.nan if r.get(k) is None else float(r[k]) for r in rows]

    panels = [("shape_rms_pct", "shape RMS error (%)"), ("timing_rms_s", "timing RMS error (s)"),
              ("longest_cell_s", "longest cell (s)"), ("clamped_fraction", "clamped fraction")]
    fig, axes = plt.subplots(1, 4, figsize=(14, 1.2 + 0.32 * len(rows)), sharey=True)
    for ax, (k, label) in zip(axes, panels, strict=True):
        ax.barh(y, np.nan_to_num(col(k)), color=c)
        ax.set_xlabel(label)
    axes[0].set_yticks(y, names, fontsize=8)
    axes[0].invert_yaxis()
    fig.suptitle("Sweep: bars coloured by verdict (green PASS, orange WARN, red FAIL)",
                 fontsize=10)
    fig.tight_layout()
    with atomic_file(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


def _claim(out: Path) -> Path:
    """The sweep folder: new, or morphshell's (every file in it recorded as written; each
    build folder in it is checked again by build() itself)."""
    return claim_result_folder(out, what="sweep folder")


def run_sweep(spec_path, *, out=None, scheduler=None, workers=None, client=None,
              progress: bool = True, dashboard: bool = False) -> dict:
    """Build every variant of a sweep spec on Dask and write the table.

    Parameters
    ----------
    spec_path : path-like
        TOML spec (module docstring).
    out : path-like, optional
        Output folder (default ``build/sweep-<name>``).
    scheduler, workers, client, dashboard
        Dask cluster (:func:`pysolver.distributed.dask_client`).
    progress : bool

    Returns
    -------
    dict
        ``rows`` (list of dict, spec order), ``out`` (str), ``run`` (RunStats dict).
    """
    scheduler, workers = check_scheduler(scheduler), check_workers(workers)
    spec = load_spec(spec_path)
    out = _claim(Path(out) if out is not None else BUILD_ROOT / f"sweep-{spec['name']}")
    tasks = []
    code = code_fingerprint()
    for v in spec["variants"]:
        files = {}
        for k in FILE_OPTIONS:
            if k in v and (k != "shape" or _is_file_like(v[k])):
                f = Path(v[k])
                files[k] = (f.name, read_input(f, f"{k} file"))
        opts = {k: val for k, val in v.items() if k not in files}
        opts["name"] = v["name"]
        dest = str(out / "builds" / v["name"])
        tasks.append(Task(v["name"], build_variant, (opts, files, dest),
                          fingerprint(opts, {k: b for k, (_, b) in files.items()}, dest,
                                      code)))
    results, stats = run_tasks(tasks, ResultStore(out / "results"), client=client,
                               scheduler=scheduler, workers=workers, progress=progress,
                               label="sweep", dashboard=dashboard)
    rows = []
    for v in spec["variants"]:
        r = dict(results.get(v["name"], {"variant": v["name"], "verdict": "ERROR",
                                         "error": stats.failed.get(v["name"], "")}))
        for k in ("shape", "vertices", "seed", "time", "material", "refine", "t_end"):
            val = v.get(k)
            r[k] = Path(val).name if (k in FILE_OPTIONS and val and _is_file_like(val)) else val
        rows.append(r)
    write_table(out, rows, spec["name"])
    n_ok = sum(r.get("verdict") != "ERROR" for r in rows)
    say("sweep", spec["name"], f"{n_ok}/{len(rows)} variants built -> {out / 'index.html'}",
        progress)
    return {"rows": rows, "out": str(out), "run": stats.to_dict()}


__all__ = ["load_spec", "run_sweep", "build_variant", "figures_row", "write_table", "COLUMNS"]
