"""Read, validate and preprocess the unit-cell tensile-test measurements.

The measurements are the tidy CSVs described in ``data/material-measurements/README.md`` (the
paper's tests, shipped with the project):

* dry quasi-static compression, one file ``unit_cell_dry_*.csv`` with the columns
  ``specimen, thickness_mm, central_length_mm, time_s, displacement_mm, force_N``
  (``bracket_length_mm``, ``sample_index`` and ``source_file`` are optional);
* constant-load creep in hot water, one file ``unit_cell_wet_*.csv`` with the same columns plus
  ``nominal_load_N`` (files named ``unit_cell_wet_speed_*`` are the plasticity-rate test and are
  not read here).

Each specimen carries **4 brackets**; force is the total on the specimen (N), displacement is the
crosshead travel (mm), both compression positive; time is seconds since the test started.

Preprocessing follows SI Note 3 and ``shared/design/material-model.md`` §2, §4:

* dry: keep rows with ``time_s < 5.25`` (the ramp; drops the 10 N hold and the snap-through of
  ``0.35_9``); the measured force is the load variable;
* wet: time in minutes; tail cut (first sample where the 10-sample moving mean of the forward
  difference rate drops below -0.1 mm/min, MATLAB's even-window ``movmean`` convention, rows after
  it dropped); strain cut (rows with ``x / b < strain_cut`` kept, a row filter); the nominal load
  from the file is the load variable.
"""

from __future__ import annotations

import csv
import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.inputs import read_input
from ..errors import InputError, refuse_first
from ..params import LIMITS, UNIT_CELL
from ..params import tol as TOL

REPO_ROOT = Path(__file__).resolve().parents[2]
"""Repository root (the folder holding ``pysolver/``)."""

DEFAULT_DATA_DIR = REPO_ROOT / "data" / "material-measurements"
"""Default measurement folder, ``<repo>/data/material-measurements`` (the paper's tensile tests,
shipped with the project; source, licence and columns in its ``README.md``)."""

SPECIMEN_BRACKETS = 4
"""Brackets per test specimen (two V-brackets per side): specimen force = 4 x bracket force."""

SCORE_STRAIN_CUT = 0.7
"""Wet rows with ``x/b`` under this score a model (:func:`wet_eval_rows`): the reference code's
cut, kept for scoring so that scores compare with the reference's; the fit itself uses
``FitOptions.wet_strain_cut``."""

STANDARD_DESIGN = {5.0: (0.30, 0.40, 0.50, 0.60), 6.0: (0.30, 0.40, 0.50, 0.60),
                   7.0: (0.30, 0.40, 0.50, 0.60), 8.0: (0.35, 0.45, 0.55, 0.65),
                   9.0: (0.35, 0.45, 0.55, 0.65)}
"""The paper's design of experiments: central length l (mm) -> thicknesses h (mm)."""

STANDARD_LOADS = {5.0: (1.0, 2.0, 3.0, 4.0), 6.0: (1.0, 2.0, 3.0, 4.0), 7.0: (1.0, 2.0, 3.0, 5.0),
                  8.0: (1.0, 2.0, 3.0, 5.0), 9.0: (1.0, 2.0, 3.0, 5.0)}
"""Nominal creep loads (N) per central length l (mm) in the paper's wet tests."""

_DRY_COLUMNS = ("specimen", "thickness_mm", "central_length_mm", "time_s", "displacement_mm",
                "force_N")
_WET_COLUMNS = _DRY_COLUMNS + ("nominal_load_N",)
_NUMERIC = ("thickness_mm", "central_length_mm", "bracket_length_mm", "time_s",
            "displacement_mm", "force_N", "nominal_load_N", "sample_index")


@dataclass
class TestTable:
    """One measurement file as column arrays, rows grouped by series in file order.

    Attributes
    ----------
    path : pathlib.Path
        The CSV file.
    sha256 : str
        Hash of the file bytes (provenance).
    specimen : (n,) str
        Series name per row (``h_l`` dry, ``h_l_F`` wet).
    series : (n,) int
        0-based series index per row, in order of first appearance.
    h, l, b : (n,) float, mm
        Bracket thickness, unit-cell central length, bracket length ``b = l - 4 cos 37deg``.
    time : (n,) float, s
        Time since the start of the test.
    x : (n,) float, mm
        Displacement (compression positive).
    force : (n,) float, N
        Measured specimen force (4 brackets).
    nominal : (n,) float, N or None
        Nominal creep load (wet files only).
    """

    path: Path
    sha256: str
    specimen: np.ndarray
    series: np.ndarray
    h: np.ndarray
    l: np.ndarray
    b: np.ndarray
    time: np.ndarray
    x: np.ndarray
    force: np.ndarray
    nominal: np.ndarray | None = None
    names: list = field(default_factory=list)

    @property
    def n_series(self) -> int:
        return len(self.names)

    def series_slices(self):
        """Yield ``(index, name, slice)`` per series (rows are contiguous by construction)."""
        starts = np.flatnonzero(np.r_[True, self.series[1:] != self.series[:-1]])
        ends = np.r_[starts[1:], len(self.series)]
        for s, e in zip(starts, ends, strict=True):
            k = int(self.series[s])
            yield k, self.names[k], slice(int(s), int(e))


@dataclass
class Measurements:
    """The dry and wet test tables of one data folder, validated.

    Attributes
    ----------
    dry, wet : TestTable
    data_dir : pathlib.Path
    missing : dict
        ``{"dry": [[h, l], ...], "wet": [[h, l], ...], "wet_loads": [[h, l, F], ...]}``: the
        combinations of the paper's standard design that the files do not contain.
    """

    dry: TestTable
    wet: TestTable
    data_dir: Path
    missing: dict

    def provenance(self) -> dict:
        """``{file name: sha256}`` of the files read."""
        return {self.dry.path.name: self.dry.sha256, self.wet.path.name: self.wet.sha256}


# ------------------------------------------------------------------------------------------------
# reading and validation


def _find_file(data_dir: Path, pattern: str, exclude: str | None, kind: str) -> Path:
    files = sorted(p for p in data_dir.glob(pattern) if not (exclude and p.match(exclude)))
    if not files:
        raise InputError(
            f"no {kind} measurement file '{pattern}' in {data_dir}.",
            fix=f"put the {kind} tests in {data_dir}/{pattern.replace('*', '<date>')} "
                "(columns as in data/material-measurements/README.md), or pass the folder "
                "that has it.")
    if len(files) > 1:
        raise InputError(
            f"{len(files)} {kind} measurement files match '{pattern}' in {data_dir}: "
            f"{', '.join(p.name for p in files)}; which one to use is ambiguous.",
            fix="keep exactly one file of each kind in the folder.")
    return files[0]


def _read_csv(path: Path, required: tuple[str, ...]) -> tuple[dict, str]:
    """Read a CSV into ``{column: list of str}``; check the header; return the sha256 too."""
    raw = read_input(path, "measurement file")
    digest = hashlib.sha256(raw).hexdigest()
    text = raw.decode("utf-8-sig")
    reader = csv.reader(text.splitlines())
    try:
        header = [c.strip() for c in next(reader)]
    except StopIteration:
        raise InputError(f"{path} is empty.", fix="give a CSV with a header row and data rows."
                         ) from None
    missing = [c for c in required if c not in header]
    if missing:
        raise InputError(
            f"{path}: missing column(s) {', '.join(missing)} (header is: {', '.join(header)}).",
            fix=f"the file needs the columns {', '.join(required)} "
                "(see data/material-measurements/README.md).")
    rows = [r for r in reader if r and any(c.strip() for c in r)]
    if not rows:
        raise InputError(f"{path} has a header but no data rows.", fix="add the measurements.")
    cols = {}
    for j, name in enumerate(header):
        cols[name] = [r[j].strip() if j < len(r) else "" for r in rows]
    return cols, digest


def _to_float(path: Path, cols: dict, name: str) -> np.ndarray:
    vals = cols[name]
    out = np.empty(len(vals))
    for i, v in enumerate(vals):
        try:
            out[i] = float(v)
        except ValueError:
            raise InputError(
                f"{path}, data row {i + 1}, column {name}: {v!r} is not a number.",
                fix="every cell of the numeric columns must be a number in the documented unit."
            ) from None
    refuse_first(~np.isfinite(out),
                 lambda i, n: f"{path}, data row {i + 1}, column {name}: value {vals[i]!r} is "
                              f"NaN/infinite ({n} such row(s) in this column).",
                 fix="remove or repair the rows with missing values.")
    return out


def _check_units(path: Path, t: TestTable, wet: bool) -> None:
    """Reject files whose columns are evidently in another unit (see module docstring)."""
    xmax = float(np.max(t.x))
    (x_lo, x_hi), (f_lo, f_hi) = LIMITS.measured_x_mm, LIMITS.measured_force_N
    h_lo, h_hi = LIMITS.measured_h_mm
    if xmax < x_lo:
        raise InputError(
            f"{path}: column displacement_mm peaks at {xmax:.3g}, but compression tests of these "
            "brackets reach 0.3-7 mm; the column looks like metres, not mm.",
            fix="convert displacement_mm to millimetres (multiply metres by 1000).")
    if xmax > x_hi:
        raise InputError(
            f"{path}: column displacement_mm peaks at {xmax:.3g}, far above any bracket length "
            "(< 10 mm); the column looks like micrometres, not mm.",
            fix="convert displacement_mm to millimetres.")
    fmax = float(np.max(np.abs(t.force)))
    if fmax < f_lo:
        raise InputError(
            f"{path}: column force_N peaks at {fmax:.3g}, but the tests load 1-10 N; the column "
            "looks like kN, not N.", fix="convert force_N to newtons.")
    if fmax > f_hi:
        raise InputError(
            f"{path}: column force_N peaks at {fmax:.3g}; the tests load 1-10 N, so the column "
            "looks like mN, not N.", fix="convert force_N to newtons.")
    tmax = float(np.max(t.time))
    if tmax < LIMITS.measured_duration_s[0 if wet else 1]:
        raise InputError(
            f"{path}: column time_s ends at {tmax:.3g}, but the tests last "
            f"{'about 2 minutes' if wet else 'about 7 s'}; the column looks like minutes or "
            "hours, not seconds.", fix="convert time_s to seconds.")
    if np.any((t.h < h_lo) | (t.h > h_hi)):
        raise InputError(
            f"{path}: thickness_mm must lie in {h_lo:g}-{h_hi:g} mm (found "
            f"{t.h.min():.3g}-{t.h.max():.3g}).",
            fix="give the bracket thickness in millimetres.")
    if np.any(t.b <= 0.0):
        raise InputError(
            f"{path}: central_length_mm {t.l.min():.3g} gives a bracket length "
            f"b = l - {UNIT_CELL.bracket_offset:.4f} <= 0.",
            fix="give the unit-cell central length (centre distance of the bases) in mm.")
    if wet and np.any(t.nominal <= 0.0):
        raise InputError(f"{path}: nominal_load_N must be > 0 N.",
                         fix="give the constant creep load of each series in newtons.")


def read_test_table(path, wet: bool) -> TestTable:
    """Read and validate one measurement CSV.

    Parameters
    ----------
    path : path-like
        ``unit_cell_dry_*.csv`` (``wet=False``) or ``unit_cell_wet_*.csv`` (``wet=True``).
    wet : bool
        Whether the file is the creep (wet) test, which needs ``nominal_load_N``.

    Returns
    -------
    TestTable

    Raises
    ------
    InputError
        Missing file or column, non-numeric or NaN cell, a column in the wrong unit, time going
        backwards within a series, or thickness/length/load changing within a series.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"measurement file {path} does not exist.",
                         fix="check the path, or pass the folder holding the CSVs.")
    required = _WET_COLUMNS if wet else _DRY_COLUMNS
    cols, digest = _read_csv(path, required)
    num = {c: _to_float(path, cols, c) for c in _NUMERIC if c in cols and c in required}
    spec = np.asarray(cols["specimen"], dtype=object)
    key = np.array([f"{s}|{f}" for s, f in zip(spec, cols.get("source_file", [""] * len(spec)),
                                                  strict=True)], dtype=object)
    names, first = [], {}
    series = np.empty(len(key), dtype=np.int64)
    for i, k in enumerate(key):
        if k not in first:
            first[k] = len(names)
            names.append(str(spec[i]))
        series[i] = first[k]
    # group rows of each series together (stable: file order within a series)
    order = np.argsort(series, kind="stable")
    h = num["thickness_mm"][order]
    l = num["central_length_mm"][order]
    b = UNIT_CELL.bracket_length(l)
    if "bracket_length_mm" in cols:
        bl = _to_float(path, cols, "bracket_length_mm")[order]
        bad = np.flatnonzero(np.abs(bl - b) > TOL.length_match)
        if bad.size:
            i = int(order[bad[0]])
            raise InputError(
                f"{path}, data row {i + 1}: bracket_length_mm = {bl[bad[0]]:.6g} but "
                f"central_length_mm - {2 * UNIT_CELL.base_r:g} cos {UNIT_CELL.alpha_deg:g}deg = "
                f"{b[bad[0]]:.6g}.",
                fix=f"bracket_length_mm must be central_length_mm - "
                    f"{UNIT_CELL.bracket_offset:.5f} mm "
                    "(or drop the column).")
    t = TestTable(path=path, sha256=digest, specimen=spec[order], series=series[order], h=h, l=l,
                  b=b, time=num["time_s"][order], x=num["displacement_mm"][order],
                  force=num["force_N"][order],
                  nominal=num["nominal_load_N"][order] if wet else None, names=names)
    for _k, name, sl in t.series_slices():
        for arr, col in ((t.h, "thickness_mm"), (t.l, "central_length_mm"),
                         (t.nominal, "nominal_load_N")):
            if arr is not None and np.ptp(arr[sl]) > TOL.rel:
                raise InputError(f"{path}: series {name!r} has more than one {col} value.",
                                 fix="each specimen (series) must have one thickness, length "
                                     "and nominal load.")
        dt = np.diff(t.time[sl])
        if np.any(dt <= 0.0):
            j = int(np.flatnonzero(dt <= 0.0)[0])
            raise InputError(
                f"{path}: series {name!r}: time_s does not increase at its sample {j + 1} "
                f"({t.time[sl][j]:.6g} -> {t.time[sl][j + 1]:.6g} s).",
                fix="rows of a series must be in time order without repeated time stamps.")
    _check_units(path, t, wet)
    return t


def _missing_design(dry: TestTable, wet: TestTable) -> dict:
    def has(t, h, l):
        return bool(np.any((np.abs(t.h - h) < TOL.same_setting)
                           & (np.abs(t.l - l) < TOL.same_setting)))

    out = {"dry": [], "wet": [], "wet_loads": []}
    for l, hs in STANDARD_DESIGN.items():
        for h in hs:
            if not has(dry, h, l):
                out["dry"].append([h, l])
            if not has(wet, h, l):
                out["wet"].append([h, l])
            for F in STANDARD_LOADS[l]:
                same = TOL.same_setting
                if not np.any((np.abs(wet.h - h) < same) & (np.abs(wet.l - l) < same)
                              & (np.abs(wet.nominal - F) < same)):
                    out["wet_loads"].append([h, l, F])
    return out


def _check_coverage(t: TestTable, kind: str, extra: str = "") -> None:
    nh = np.unique(np.round(t.h, 6)).size
    nb = np.unique(np.round(t.b, 6)).size
    pairs = np.unique(np.round(np.c_[t.h, t.b], 6), axis=0)
    if nh < 2 or nb < 2 or len(pairs) < 3:
        raise InputError(
            f"{t.path}: {kind} tests cover {nh} thickness(es), {nb} length(s) and "
            f"{len(pairs)} (thickness, length) specimen(s); the model needs at least 2 "
            "thicknesses, 2 lengths and 3 specimens not all on one line to separate the "
            f"effects of h and b{extra}.",
            fix="add specimens of other thicknesses and lengths (the paper tests 20: "
                "l = 5..9 mm x 4 thicknesses).")


def load_measurements(data_dir=None) -> Measurements:
    """Read and validate the dry and wet unit-cell measurements of a folder.

    Parameters
    ----------
    data_dir : path-like, optional
        Folder with one ``unit_cell_dry_*.csv`` and one ``unit_cell_wet_*.csv``. Default
        :data:`DEFAULT_DATA_DIR` (``<repo>/data/material-measurements``).

    Returns
    -------
    Measurements
        ``missing`` lists the combinations of the paper's standard design absent from the files;
        the fit still runs without them (the model interpolates through the gap).

    Raises
    ------
    InputError
        Missing folder/file/column, wrong units, NaNs, or too few specimens.
    """
    data_dir = Path(DEFAULT_DATA_DIR if data_dir is None else data_dir)
    if not data_dir.is_dir():
        raise InputError(f"measurement folder {data_dir} does not exist.",
                         fix="pass the folder holding unit_cell_dry_*.csv and "
                             "unit_cell_wet_*.csv (default data/material-measurements).")
    dry = read_test_table(_find_file(data_dir, "unit_cell_dry_*.csv", None, "dry"), wet=False)
    wet = read_test_table(_find_file(data_dir, "unit_cell_wet_*.csv", "unit_cell_wet_speed_*",
                                     "wet"), wet=True)
    _check_coverage(dry, "dry")
    _check_coverage(wet, "wet")
    loads = np.unique(np.round(wet.nominal, 6))
    if loads.size < 2:
        raise InputError(
            f"{wet.path}: all creep series use the same nominal load {loads[0]:g} N; the creep "
            "rate model needs at least 2 loads to separate the load dependence.",
            fix="add series at other constant loads (the paper uses 1, 2, 3 and 4 or 5 N).")
    return Measurements(dry=dry, wet=wet, data_dir=data_dir, missing=_missing_design(dry, wet))


# ------------------------------------------------------------------------------------------------
# preprocessing


@dataclass
class Observations:
    """Preprocessed rows ready for fitting (all arrays (n,)).

    Attributes
    ----------
    h, b : float, mm
    F : float, N
        Specimen load (measured force dry, nominal load wet).
    x : float, mm
    t : float, min
        Time in water (wet) or 0 (dry).
    series : int
        Series index into ``names``.
    names : list of str
    """

    h: np.ndarray
    b: np.ndarray
    F: np.ndarray
    x: np.ndarray
    t: np.ndarray
    series: np.ndarray
    names: list

    def __len__(self) -> int:
        return len(self.x)

    def subset(self, mask) -> Observations:
        return Observations(self.h[mask], self.b[mask], self.F[mask], self.x[mask], self.t[mask],
                            self.series[mask], self.names)


def preprocess_dry(dry: TestTable, time_cut_s: float = 5.25) -> Observations:
    """Dry rows used by the fit: ``time_s < time_cut_s``; load = measured force.

    Parameters
    ----------
    dry : TestTable
    time_cut_s : float, s

    Returns
    -------
    Observations
        ``t`` is 0.
    """
    keep = dry.time < time_cut_s
    return Observations(dry.h[keep], dry.b[keep], dry.force[keep], dry.x[keep],
                        np.zeros(int(keep.sum())), dry.series[keep], dry.names)


def movmean_even(d: np.ndarray, k: int) -> np.ndarray:
    """Moving mean with MATLAB ``movmean(d, k)`` windows for even ``k``: ``i-k/2 .. i+k/2-1``.

    The window shrinks at both ends (mean over the samples that exist).  Written with a cumulative
    sum because numpy/scipy have no shrinking-window mean with this (asymmetric) alignment.
    """
    n = len(d)
    c = np.r_[0.0, np.cumsum(d)]
    i = np.arange(n)
    lo = np.clip(i - k // 2, 0, n)
    hi = np.clip(i + k // 2, 0, n)  # exclusive end: i + k/2 - 1 inclusive
    return (c[hi] - c[lo]) / (hi - lo)


def tail_cut_index(t_min: np.ndarray, x: np.ndarray, rate_min: float = -0.1,
                   window: int = 10) -> int:
    """Number of leading rows kept by the tail cut (material-model.md §4 step 2).

    Parameters
    ----------
    t_min : (n,) float, min
    x : (n,) float, mm
    rate_min : float, mm/min
        Threshold on the moving-mean forward-difference rate.
    window : int
        Moving-mean window (even).

    Returns
    -------
    int
        Rows ``0 .. k-1`` are kept; ``k = n`` when the rate never drops below the threshold.
    """
    if len(x) < 2:
        return len(x)
    d = np.diff(x) / np.diff(t_min)
    m = movmean_even(d, window)
    hit = np.flatnonzero(m < rate_min)
    return len(x) if hit.size == 0 else int(hit[0]) + 1


def preprocess_wet(wet: TestTable, strain_cut: float = SCORE_STRAIN_CUT,
                   tail_rate: float = -0.1, window: int = 10,
                   apply_strain_cut: bool = True) -> Observations:
    """Wet rows used by the fit (material-model.md §4).

    Parameters
    ----------
    wet : TestTable
    strain_cut : float
        Keep rows with ``x / b < strain_cut`` (a row filter, not a truncation).
    tail_rate : float, mm/min
    window : int
    apply_strain_cut : bool
        False keeps every row up to the tail cut (used to plot whole curves).

    Returns
    -------
    Observations
        ``t`` in minutes, ``F`` the nominal load (N).
    """
    keep = np.zeros(len(wet.x), dtype=bool)
    t_min = wet.time / 60.0
    for _k, _name, sl in wet.series_slices():
        n = tail_cut_index(t_min[sl], wet.x[sl], tail_rate, window)
        keep[sl.start:sl.start + n] = True
    if apply_strain_cut:
        keep &= wet.x / wet.b < strain_cut
    return Observations(wet.h[keep], wet.b[keep], wet.nominal[keep], wet.x[keep], t_min[keep],
                        wet.series[keep], wet.names)


def wet_eval_rows(wet: TestTable, t_max_s: float,
                  strain_cut: float = SCORE_STRAIN_CUT) -> Observations:
    """Wet rows that score a bracket model: tail cut, ``x/b < strain_cut``, ``t <= t_max_s``.

    Parameters
    ----------
    wet : TestTable
    t_max_s : float, s
        The end of the scored model's time grid (``model.grid_max[2]``): the model is not
        fitted beyond it.
    strain_cut : float
    """
    obs = preprocess_wet(wet, strain_cut=strain_cut)
    return obs.subset(obs.t * 60.0 <= t_max_s + TOL.rel)


def creep_rates(obs: Observations, floor: float = 0.01):
    """Log creep-rate observations of SI eq. 10 and equal-weight-per-curve weights.

    Rows are sorted (stably) by (h, b, F, t); forward differences give the rate
    ``dx/dt`` (mm/min) at the left sample; rates below ``floor`` (including negative ones) are
    floored; the last sample of each series has no forward difference and is dropped.

    Parameters
    ----------
    obs : Observations
        Wet observations (``t`` in minutes).
    floor : float, mm/min

    Returns
    -------
    X : (m, 4) float
        Columns h (mm), b (mm), F (N), t (min).
    y : (m,) float, ln(mm min^-1 N^-1)
        ``ln(max(floor, dx/dt) / F)``.
    w : (m,) float
        ``min_k n_k / n_series`` so every series carries the same total weight.
    series : (m,) int
    """
    order = np.lexsort((obs.t, obs.series, obs.F, obs.b, obs.h))
    h, b, F, t, x, s = (a[order] for a in (obs.h, obs.b, obs.F, obs.t, obs.x, obs.series))
    dt = np.r_[np.diff(t), -1.0]
    dx = np.r_[np.diff(x), 0.0]
    ok = (dt > 0.0) & np.r_[s[1:] == s[:-1], False]
    rate = np.maximum(floor, dx[ok] / dt[ok])
    y = np.log(rate / F[ok])
    s = s[ok]
    counts = np.bincount(s, minlength=s.max() + 1)
    w = counts[counts > 0].min() / counts[s]
    return np.c_[h[ok], b[ok], F[ok], t[ok]], y, w.astype(float), s
