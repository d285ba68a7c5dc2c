"""Compare a 3D scan of a printed, morphed shell with the simulation (marker dots).

Every base except the alignment bases carries a coloured marker dot on the far
face of each layer (``design/pipeline.md`` §1.5); a scan of the morphed shell
gives their positions as a point set, read as given (an OBJ of ``v`` lines, a PLY or
x y z columns), usually with some markers missing.  :func:`compare_scan` registers that
point set to the simulated marker tips (``marker_top`` / ``marker_bottom`` in
``sim/frames.npz``; the dry resting shape ``rest_marker_*`` when the simulation has
one, since scans are of dried shells) and reports the distances, by the procedure of
the printed shells' data (``../shared/printed-shells/README.md``): rigid registration
without scaling (ICP, then one-to-one matching, then the rigid fit minimising the sum of
the matched distances), and the mean matched distance.

1. **Starts**: centroids (median) and principal axes of both sets; 24 starts =
   principal frames x 12 rotations of 30 deg about the smallest-variance axis (the
   shell's mean normal) x 2 flips, plus the 24 rotations of the cube group.
2. **Trimmed ICP** from every start (nearest marker per scan point, keep the closest
   80 %, Kabsch).
3. **One-to-one matching** (:func:`scipy.optimize.linear_sum_assignment`): every scan
   point gets its own marker (a scan has at most as many dots as there are markers;
   extra points stay unmatched).  With a ``gate`` (optional), pairs farther than it are
   outliers and left out.
4. **L1 rigid fit**: the rigid motion minimising the *sum* of distances of the matched
   pairs, by iteratively re-weighted Kabsch (weights 1/distance), alternated with
   re-matching until the matches stop changing.

Steps 3-4 run from the best distinct ICP results, and the registration with the lowest
sum of matched distances is kept: a shell that is long and curled (a spiral) has local
optima one marker row apart, about a millimetre worse (issue #32).  ``layer="auto"``
registers both layers and keeps the one with the lower mean.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree
from scipy.spatial.distance import pdist
from scipy.spatial.transform import Rotation

from pysolver.core.inputs import check_input_file, read_input
from pysolver.core.ownership import claim_result_folder
from pysolver.core.records import json_text
from pysolver.core.writes import atomic_file, atomic_write_text, make_dirs
from pysolver.errors import InputError
from pysolver.geometry import rigid_fit
from pysolver.params import tol as TOL
from pysolver.tables import read_table

from .load import load_frames

TRIM_FRACTION = 0.8
"""Fraction of closest pairs kept by each trimmed-ICP iteration (allows 20 % missing/outliers)."""
ICP_MAX_ITER = 60
MATCH_MAX_ITER = 20
"""Rounds of one-to-one matching + L1 fit (they stop earlier when the matches repeat)."""
REFINE_CANDIDATES = 16
"""Distinct ICP results refined by matching + L1 fit (the best by their truncated score)."""
DISTINCT_DEG, DISTINCT_MM = 2.0, 1.0
"""Two ICP results closer than this (rotation, translation) are the same candidate."""
IRLS_MAX_ITER = 100


# --------------------------------------------------------------------------------------------
# rigid fits
# --------------------------------------------------------------------------------------------

def l1_rigid_fit(A, B, *, Q0=None, s0=None, max_iter=IRLS_MAX_ITER, eps=TOL.irls_eps_mm):
    """Rigid motion minimising the sum of distances ``sum_i |Q a_i + s - b_i|`` (IRLS).

    Iteratively re-weighted Kabsch with weights ``1 / max(d_i, eps)``; each step
    does not increase the objective (majorise-minimise).

    Parameters
    ----------
    A, B : (n, 3) float, mm
    Q0, s0 : optional start (default: the least-squares fit)

    Returns
    -------
    Q : (3, 3) float
    s : (3,) float, mm
    """
    if Q0 is None:
        Q, s = rigid_fit(A, B)
    else:
        Q, s = Q0, s0
    prev = np.inf
    for _ in range(max_iter):
        d = np.linalg.norm(A @ Q.T + s - B, axis=1)
        obj = d.sum()
        if prev - obj <= TOL.irls_rel * max(obj, TOL.exact):
            break
        prev = obj
        Q, s = rigid_fit(A, B, weights=1.0 / np.maximum(d, eps))
    return Q, s


# --------------------------------------------------------------------------------------------
# reading scans
# --------------------------------------------------------------------------------------------

def read_points(path):
    """Read a point set: OBJ (``v`` lines), PLY (via trimesh) or CSV/TXT/XYZ (x y z columns).

    Returns
    -------
    P : (n, 3) float, mm
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: file not found", fix="give the path of the scan point set")
    check_input_file(path, "scan file")  # a FIFO or a device would block the reader
    ext = path.suffix.lower()
    if ext == ".obj":
        # hand-written: an OBJ of bare vertices is not a mesh for trimesh (it loads as empty)
        pts = []
        with open(path, errors="replace") as fh:
            for ln, line in enumerate(fh, start=1):
                parts = line.split()
                if parts and parts[0] == "v":
                    try:
                        pts.append([float(x) for x in parts[1:4]])
                    except ValueError:
                        raise InputError(f"{path}:{ln}: cannot parse {line.strip()!r}") from None
        P = np.array(pts, float).reshape(-1, 3)
    elif ext == ".ply":
        import trimesh  # heavy: trimesh loads only for STL work

        try:
            geom = trimesh.load(io.BytesIO(read_input(path, "scan file")), file_type="ply",
                                process=False)  # (no resolver: names in it are not opened)
        except Exception as e:
            raise InputError(f"{path}: cannot read PLY ({type(e).__name__}: {e})") from None
        P = np.asarray(getattr(geom, "vertices", np.zeros((0, 3))), float).reshape(-1, 3)
    elif ext in (".csv", ".txt", ".xyz"):
        rows = []
        with open(path, errors="replace") as fh:
            for ln, line in enumerate(fh, start=1):
                s = line.strip()
                if not s or s.startswith("#"):
                    continue
                fields = s.replace(",", " ").replace(";", " ").split()
                try:
                    vals = [float(x) for x in fields[:3]]
                except ValueError:
                    if rows:
                        raise InputError(f"{path}:{ln}: not numbers: {s!r}") from None
                    continue  # header line
                if len(vals) != 3:
                    raise InputError(f"{path}:{ln}: need 3 columns x y z, got {s!r}")
                rows.append(vals)
        P = np.array(rows, float).reshape(-1, 3)
    else:
        raise InputError(f"{path}: unknown point-set format {ext!r}",
                         fix="use .obj (v lines), .ply, or .csv/.txt/.xyz with x y z columns")
    if len(P) < 3:
        raise InputError(f"{path}: {len(P)} points, need at least 3",
                         fix="check that the file holds the detected marker dots")
    if not np.isfinite(P).all():
        raise InputError(f"{path}: NaN or infinite coordinates")
    return P


STATES = ("auto", "final", "rest")
"""Which simulated shape a scan is compared with: ``final`` = the last frame in water,
``rest`` = the dry resting shape (``--physics dry-rest``), ``auto`` = rest when present."""


def simulated_markers(design_dir, layer, frame=-1, state="final"):
    """Simulated marker-dot tips of one layer, without alignment bases.

    Parameters
    ----------
    design_dir : path-like
    layer : {"top", "bottom"}
    frame : int -- frame of the morph (``state="final"``)
    state : {"final", "rest", "auto"} -- the frame, or the dry resting shape (:data:`STATES`)

    Returns
    -------
    M : (k, 3) float, mm
    base_ids : (k,) int
    """
    folder = Path(design_dir)
    bases = read_table(folder, "bases")
    fr = load_frames(folder / "sim" / "frames.npz", len(bases["base_id"]))
    rest = f"rest_marker_{layer}"
    if state == "rest" and rest not in fr:
        raise InputError(f"{folder / 'sim/frames.npz'}: no dry resting shape ({rest})",
                         fix="simulate with --physics ...,dry-rest, or compare the final "
                             "frame (--state final)")
    if state in ("rest", "auto") and rest in fr:
        M = np.asarray(fr[rest], float)
    else:
        key = f"marker_{layer}"
        if key not in fr:
            raise InputError(f"{folder / 'sim/frames.npz'}: no {key} array",
                             fix="re-run the simulation with the current sim.model.simulate")
        M = np.asarray(fr[key][frame], float)
    keep = ~bases["alignment"].astype(bool) & np.isfinite(M).all(axis=1)
    return M[keep], np.flatnonzero(keep)


# --------------------------------------------------------------------------------------------
# registration
# --------------------------------------------------------------------------------------------

def _pca(P):
    c = np.median(P, axis=0)
    X = P - P.mean(axis=0)
    w, V = np.linalg.eigh(X.T @ X)
    V = V[:, ::-1]                   # largest variance first; column 2 = normal axis
    if np.linalg.det(V) < 0:
        V[:, 2] *= -1
    return c, V


def _start_rotations(P, M):
    """Candidate rotations taking the scan's principal frame onto the markers'."""
    _, Vp = _pca(P)
    _, Vm = _pca(M)
    starts = []
    for flip in (False, True):
        F = np.diag([1.0, -1.0, -1.0]) if flip else np.eye(3)  # 180 deg about the major axis
        for k in range(12):
            a = np.radians(30.0 * k)
            Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
            starts.append(Vm @ Rz @ F @ Vp.T)
    for g in Rotation.create_group("O").as_matrix():
        starts.append(Vm @ g @ Vp.T)
    return starts


def _trimmed_icp(P, tree, M, Q, s, max_iter=ICP_MAX_ITER, trim=TRIM_FRACTION):
    n_keep = max(3, int(np.ceil(trim * len(P))))
    prev = None
    for _ in range(max_iter):
        X = P @ Q.T + s
        d, j = tree.query(X)
        keep = np.argpartition(d, n_keep - 1)[:n_keep]
        Q, s = rigid_fit(P[keep], M[j[keep]])
        key = (j[keep].tobytes(), keep.tobytes())
        if key == prev:
            break
        prev = key
    return Q, s


def _score(P, tree, Q, s, gate):
    d, _ = tree.query(P @ Q.T + s)
    return float(np.mean(np.minimum(d, gate)))


def _match_and_fit(P, M, Q, s, gate):
    """Alternate one-to-one matching and the L1 rigid fit until the matches repeat.

    Returns ``(objective, Q, s, r, c)``: sum of matched distances (mm), transform, matched
    scan and marker indices."""
    prev = None
    r = c = np.zeros(0, dtype=np.int64)
    for _ in range(MATCH_MAX_ITER):
        X = P @ Q.T + s
        D = np.linalg.norm(X[:, None, :] - M[None, :, :], axis=2)
        r, c = linear_sum_assignment(D if gate is None else np.minimum(D, gate))
        if gate is not None:
            ok = D[r, c] < gate
            r, c = r[ok], c[ok]
        if len(r) < 3:
            break
        key = (r.tobytes(), c.tobytes())
        if key == prev:
            break
        prev = key
        Q, s = l1_rigid_fit(P[r], M[c], Q0=Q, s0=s)
    X = P @ Q.T + s
    d = np.linalg.norm(X[r] - M[c], axis=1)
    return float(d.sum()), Q, s, r, c


def register(P, M, *, gate=None):
    """Register scan points ``P`` to markers ``M`` (rigid), then match them one-to-one.

    Parameters
    ----------
    P : (n, 3) float, mm
        Scan points (any order, may miss markers).
    M : (k, 3) float, mm
        Simulated marker tips.
    gate : float, mm, optional
        Outlier rejection: matches farther than this are left out.  Default none (the
        printed shells' procedure): every scan point is matched when ``n <= k``.

    Returns
    -------
    dict with ``Q`` (3, 3), ``s`` (3,) (scan -> simulation: ``x -> Q x + s``),
    ``pairs`` (m, 2) int (scan index, marker index), ``dist`` (m,) mm,
    ``outliers`` (scan indices without a match), ``gate_mm`` (None without a gate),
    ``score_mm`` (mean nearest-marker distance, capped at half the median marker
    spacing), ``candidates`` (registrations refined).
    """
    P = np.asarray(P, float)
    M = np.asarray(M, float)
    if len(M) < 3:
        raise InputError(f"{len(M)} simulated markers, need at least 3 to register a scan")
    tree = cKDTree(M)
    dnn, _ = tree.query(M, k=2)
    cap = 0.5 * float(np.median(dnn[:, 1]))
    gate = None if gate is None else float(gate)
    cm, _ = _pca(M)
    cp, _ = _pca(P)
    cand = []
    for Q0 in _start_rotations(P, M):
        Q, s = _trimmed_icp(P, tree, M, Q0, cm - Q0 @ cp)
        cand.append((_score(P, tree, Q, s, cap), Q, s))
    cand.sort(key=lambda c: c[0])
    distinct = []
    for sc, Q, s in cand:
        if all(np.degrees(Rotation.from_matrix(Q @ Q2.T).magnitude()) > DISTINCT_DEG
               or np.linalg.norm(s - s2) > DISTINCT_MM for _, Q2, s2 in distinct):
            distinct.append((sc, Q, s))
        if len(distinct) == REFINE_CANDIDATES:
            break
    best = None
    for _, Q, s in distinct:
        res = _match_and_fit(P, M, Q, s, gate)
        # the most matches first (with a gate), then the lowest sum of distances
        key = (-len(res[3]), res[0])
        if best is None or key < best[0]:
            best = (key, res)
    _, (_, Q, s, r, c) = best
    X = P @ Q.T + s
    dist = np.linalg.norm(X[r] - M[c], axis=1)
    outliers = np.setdiff1d(np.arange(len(P)), r)
    return {"Q": Q, "s": s, "pairs": np.c_[r, c], "dist": dist, "outliers": outliers,
            "gate_mm": gate, "score_mm": _score(P, tree, Q, s, cap),
            "candidates": len(distinct)}


# --------------------------------------------------------------------------------------------
# the comparison
# --------------------------------------------------------------------------------------------

def _stats(reg, P, M):
    d = reg["dist"]
    diam = float(pdist(M).max()) if len(M) > 1 else float("nan")
    Q = reg["Q"]
    return {
        "matched": int(len(d)), "n_scan": int(len(P)), "n_markers": int(len(M)),
        "outliers": int(len(reg["outliers"])),
        "unmatched_markers": int(len(M) - len(d)),
        "mean_mm": float(d.mean()) if d.size else float("nan"),
        "max_mm": float(d.max()) if d.size else float("nan"),
        "std_mm": float(d.std()) if d.size else float("nan"),
        "median_mm": float(np.median(d)) if d.size else float("nan"),
        "rms_mm": float(np.sqrt(np.mean(d ** 2))) if d.size else float("nan"),
        "diameter_mm": diam,
        "mean_over_diameter": float(d.mean() / diam) if d.size and diam > 0 else float("nan"),
        "gate_mm": reg["gate_mm"], "score_mm": reg["score_mm"],
        "rotation_deg": float(np.degrees(Rotation.from_matrix(Q).magnitude())),
        "transform_scan_to_sim": {"R": Q.tolist(), "t_mm": reg["s"].tolist()},
    }


def plot_error_on_shell(ax, flat_xy, base_ids, err, *, vmax=None, title=""):
    """The flat layout of the bases, the scanned ones coloured by their error (mm).

    Parameters
    ----------
    ax : matplotlib Axes
    flat_xy : (m, 2) float, mm -- flat base centres (``bases.csv``)
    base_ids : (k,) int -- bases with a matched scan dot
    err : (k,) float, mm -- their distance to the scan
    vmax : float, mm, optional -- top of the colour scale (default the largest error)

    Returns
    -------
    the scatter (for a colour bar)
    """
    ax.scatter(*flat_xy.T, s=6, c="lightgray", label="not scanned")
    vmax = float(np.max(err)) if vmax is None and len(err) else vmax
    sc = ax.scatter(*flat_xy[base_ids].T, s=26, c=err, cmap="magma_r", vmin=0.0, vmax=vmax,
                    edgecolors="k", linewidths=0.2)
    ax.set_aspect("equal")
    ax.set_xlabel("flat x (mm)")
    ax.set_ylabel("flat y (mm)")
    ax.set_title(title, fontsize=9)
    return sc


def _plot(path, P, M, reg, title, flat_xy=None, ids=None):
    import matplotlib  # optional heavy dependency: matplotlib loads only when a picture is drawn

    matplotlib.use("Agg")
    # optional heavy dependency: matplotlib loads only when a picture is drawn
    import matplotlib.pyplot as plt

    # optional heavy dependency: matplotlib loads only when a picture is drawn
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    X = P @ reg["Q"].T + reg["s"]
    pr = reg["pairs"]
    d = reg["dist"]
    on_shell = flat_xy is not None and ids is not None
    fig = plt.figure(figsize=(16 if on_shell else 11, 5))
    ncol = 3 if on_shell else 2
    ax = fig.add_subplot(1, ncol, 1, projection="3d")
    ax.scatter(*M.T, s=8, c="tab:blue", label=f"simulated markers ({len(M)})", depthshade=False)
    ax.scatter(*X[pr[:, 0]].T, s=8, c="tab:orange", label=f"scan, matched ({len(pr)})",
               depthshade=False)
    if len(reg["outliers"]):
        ax.scatter(*X[reg["outliers"]].T, s=18, c="red", marker="x",
                   label=f"scan, outliers ({len(reg['outliers'])})", depthshade=False)
    if len(pr):
        segs = np.stack([X[pr[:, 0]], M[pr[:, 1]]], axis=1)
        lc = Line3DCollection(segs, colors=plt.cm.plasma(d / max(d.max(), TOL.rel)), linewidths=1.5)
        ax.add_collection3d(lc)
    allp = np.concatenate([M, X])
    mid = 0.5 * (allp.min(0) + allp.max(0))
    half = 0.5 * np.ptp(M, axis=0).max() * 1.1
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title(title, fontsize=9)
    if on_shell:
        ax3 = fig.add_subplot(1, ncol, 2)
        sc = plot_error_on_shell(ax3, flat_xy, ids[pr[:, 1]], d,
                                 title="error on the shell (flat layout)")
        fig.colorbar(sc, ax=ax3, label="scan dot - simulated marker (mm)")
    ax2 = fig.add_subplot(1, ncol, ncol)
    if len(d):
        ax2.hist(d, bins=min(40, max(5, len(d) // 5)), color="tab:orange")
        ax2.axvline(d.mean(), color="k", ls="--", label=f"mean {d.mean():.2f} mm")
        if reg["gate_mm"] is not None:
            ax2.axvline(reg["gate_mm"], color="red", ls=":",
                        label=f"gate {reg['gate_mm']:.2f} mm")
        ax2.legend(fontsize=8)
    ax2.set_xlabel("distance scan dot - simulated marker (mm)")
    ax2.set_ylabel("matched pairs")
    ax2.set_title("matched-pair distances")
    fig.tight_layout()
    with atomic_file(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
    return path


def compare_scan(design_dir, scan_path, *, layer="auto", out_dir=None, gate_mm=None,
                 frame=-1, state="auto", progress=True) -> dict:
    """Compare scanned marker dots with the simulated marker tips.

    Parameters
    ----------
    design_dir : path-like
        Design folder with ``bases.csv`` and ``sim/frames.npz``.
    scan_path : path-like
        Point set of detected marker dots, mm: OBJ vertices, PLY, or CSV x y z.
    layer : {"auto", "top", "bottom"}
        Which layer's markers were scanned; "auto" keeps the layer with the lower mean.
    out_dir : path-like, optional
        Where ``scan_<stem>.json`` and ``scan_<stem>.png`` go (default
        ``<design_dir>/scan_report``; not inside ``report/``, which the report
        stage replaces as a whole).
    gate_mm : float, mm, optional
        Outlier rejection (matches farther than this are left out); default none, the
        printed shells' procedure (every scan dot is matched).
    frame : int
        Simulation frame to compare with (default the last; ``state="final"``).
    state : {"auto", "final", "rest"}
        The final frame in water, or the dry resting shape on a table (``rest``, from
        ``--physics dry-rest``); ``auto`` (default) takes the resting shape when the
        simulation has one: scanned shells are dry.
    progress : bool
        Print the result line.

    Returns
    -------
    dict
        ``layer``, ``state``, ``mean_mm``, ``max_mm``, ``std_mm``, ``mean_over_diameter``,
        ``matched``, ``outliers``, ``unmatched_markers``, ``transform_scan_to_sim``,
        ``per_layer`` (auto), ``pairs`` (scan index, base id, distance), ``files``.

    Examples
    --------
    A "scan" of the simulated top markers of the ``folder`` of
    :func:`sim.model.simulate.simulate_design`'s example, moved 5 mm: the registration
    undoes the move.

    >>> import numpy as np
    >>> from sim.report.scan import compare_scan, simulated_markers
    >>> M, _ = simulated_markers(folder, "top")
    >>> np.savetxt(tmp / "dots.csv", M + [5.0, 0.0, 0.0], delimiter=",")
    >>> r = compare_scan(folder, tmp / "dots.csv", layer="top", progress=False)
    >>> r["matched"] == len(M), r["mean_mm"] < 1e-6
    (True, True)
    """
    if layer not in ("auto", "top", "bottom"):
        raise InputError(f"layer = {layer!r}", fix="use 'auto', 'top' or 'bottom'")
    if state not in STATES:
        raise InputError(f"state = {state!r}", fix=f"use one of {', '.join(STATES)}")
    if gate_mm is not None and not (np.isfinite(gate_mm) and gate_mm > 0):
        raise InputError(f"gate = {gate_mm!r} mm", fix="give a positive distance in mm")
    folder = Path(design_dir)
    scan_path = Path(scan_path)
    P = read_points(scan_path)
    layers = ("top", "bottom") if layer == "auto" else (layer,)
    results = {}
    for ly in layers:
        M, ids = simulated_markers(folder, ly, frame, state)
        reg = register(P, M, gate=gate_mm)
        results[ly] = (M, ids, reg)
    chosen = min(results, key=lambda k: (-len(results[k][2]["dist"]),
                                         float(results[k][2]["dist"].mean())))
    M, ids, reg = results[chosen]
    with np.load(folder / "sim" / "frames.npz", allow_pickle=False) as z:
        has_rest = f"rest_marker_{chosen}" in z.files
    used = "rest" if state in ("rest", "auto") and has_rest else "final"
    out = {"design_dir": str(folder), "scan": str(scan_path), "layer": chosen,
           "layer_option": layer, "state": used, **_stats(reg, P, M)}
    if layer == "auto":
        out["per_layer"] = {k: {kk: vv for kk, vv in _stats(v[2], P, v[0]).items()
                                if kk in ("mean_mm", "max_mm", "matched", "score_mm")}
                            for k, v in results.items()}
    out["pairs"] = [[int(a), int(ids[b]), float(d)] for (a, b), d in
                    zip(reg["pairs"], reg["dist"], strict=True)]
    if out_dir is None:
        out_dir = make_dirs(folder / "scan_report")   # recorded in the design folder's stamp
    else:   # a folder of its own, stamped, so that a rerun may replace what it wrote
        out_dir = claim_result_folder(out_dir, what="scan output folder", inputs=[scan_path])
    stem = scan_path.stem
    bases = read_table(folder, "bases")
    flat = np.c_[bases["flat_x_mm"], bases["flat_y_mm"]]
    png = _plot(out_dir / f"scan_{stem}.png", P, M, reg,
                f"{scan_path.name} vs simulated {chosen} markers ({used}): mean "
                f"{out['mean_mm']:.2f} mm", flat_xy=flat, ids=ids)
    out["files"] = {"png": str(png), "json": str(out_dir / f"scan_{stem}.json")}

    atomic_write_text(out_dir / f"scan_{stem}.json",
                      json_text(out, sort_keys=False, strict=True))
    if progress:
        print(f"scan vs simulation ({chosen} layer, {used} shape): mean {out['mean_mm']:.3f} mm, "
              f"max {out['max_mm']:.3f} mm, std {out['std_mm']:.3f} mm, mean/diameter "
              f"{100 * out['mean_over_diameter']:.2f} %, {out['matched']} matched, "
              f"{out['outliers']} outliers -> {png}")
    return out


def main(argv=None) -> int:

    ap = argparse.ArgumentParser(prog="python -m sim.report.scan",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("design_dir")
    ap.add_argument("scan")
    ap.add_argument("--layer", default="auto", choices=("auto", "top", "bottom"))
    ap.add_argument("--state", default="auto", choices=STATES)
    ap.add_argument("--gate-mm", type=float, default=None)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    compare_scan(a.design_dir, a.scan, layer=a.layer, out_dir=a.out, state=a.state,
                 gate_mm=a.gate_mm)
    return 0


__all__ = ["l1_rigid_fit", "read_points", "simulated_markers", "register",
           "compare_scan", "plot_error_on_shell", "STATES"]

if __name__ == "__main__":
    sys.exit(main())
