"""Collision checks along a simulated morph, and unit-cell completion times.

The simulator has no self-contact (simulator.md §9: only the per-bracket bumper
switch), so a morph can pass one part of the shell through another without the
solver noticing.  This module finds such events after the fact, frame by frame:

* **base vs base**: every base is a solid cylinder of radius ``base_r`` (2 mm)
  and height ``2 * layer_h`` (4.6 mm) centred on the membrane mid-plane (both
  printed discs of a base plus the membrane between them).  Two bases that do
  not share a unit cell must never overlap.  Neighbours (sharing a cell) are
  skipped: their bumpers are designed to touch.
* **membrane vs base**: a membrane vertex must not lie inside a base it was not
  close to in the flat layout (flat distance from the base centre above
  ``base_r + max_cell_length``), which catches one part of the shell folding
  through another.

Broad phase: a :class:`scipy.spatial.cKDTree` on the base centres of each
frame, queried with the cylinders' bounding-sphere diameter.  Narrow phase:
signed distance of one cylinder evaluated at surface samples of the other
(both ways), vectorised over all candidate pairs.  Sampling resolves
penetrations down to about 0.05 mm (rim samples 0.52 mm apart on a 2 mm
radius: chord sag 0.017 mm); see ``docs/report.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from pysolver.errors import InputError
from pysolver.params import UNIT_CELL

# --------------------------------------------------------------------------------------------
# completion times
# --------------------------------------------------------------------------------------------

def completion_times(frames, collided=None, *, rule: str = "clearance",
                     bracket_length=None, collision_length=None,
                     tol_mm: float = UNIT_CELL.clearance) -> np.ndarray:
    """Completion time of every unit cell: the first frame at which its brackets reach
    their bumpers.  This is the project's single definition (temporal programming, the
    report and the benchmarks all use it).

    Rules:

    * ``"clearance"`` (default): each of the 4 bracket springs is collided or within
      ``tol_mm`` (0.05 mm, the size of the printing clearance) of its bumper contact length
      (``collision_length``: the printed bumpers' with ``PhysicsOptions.clearance``).  In
      irregular stencils the two springs of a layer have contact lengths a few hundredths
      of a millimetre apart, so a cell often closes one end and stays a hair short at the
      other, which a printed part could not tell apart from closed.  Needs
      ``bracket_length`` and ``collision_length`` (in ``frames.npz``); without them it is
      ``"all"``.
    * ``"all"``: all four springs collided (exact contact).
    * ``"layer"``: in each layer, one of its two springs collided.

    Parameters
    ----------
    frames : dict, path-like, or (n_frames,) float array
        Frames (``frames.npz`` content or its path), or the frame times ``t`` (s) when
        ``collided`` is given.
    collided : (n_frames, n_cells, 4) bool, optional
        Spring order ``2 * layer + q`` (layer 0 = top).
    rule : {"clearance", "all", "layer"}
    bracket_length : (n_frames, n_cells, 4) float, mm, optional
    collision_length : (n_cells, 4) float, mm, optional
    tol_mm : float, mm

    Returns
    -------
    t_done : (n_cells,) float, s
        NaN for cells that never complete.
    """
    if collided is None:
        frames = read_completion_frames(frames)
        t, collided = np.asarray(frames["t"], float), np.asarray(frames["collided"])
        if bracket_length is None and "bracket_length" in frames:
            bracket_length = frames["bracket_length"]
        if collision_length is None and "collision_length" in frames:
            collision_length = frames["collision_length"]
    else:
        t = np.asarray(frames, float)
        collided = np.asarray(collided)
    c = _checked_collided(collided, t)
    if rule == "clearance":
        c = _closed(c, bracket_length, collision_length, tol_mm, len(t))
        done = c.all(axis=2)
    elif rule == "all":
        done = c.all(axis=2)
    elif rule == "layer":
        done = (c[:, :, 0] | c[:, :, 1]) & (c[:, :, 2] | c[:, :, 3])
    else:
        raise InputError(f"rule must be 'clearance', 'all' or 'layer', got {rule!r}")
    first = np.argmax(done, axis=0)
    return np.where(done.any(axis=0), t[first], np.nan)


def read_completion_frames(frames) -> dict:
    """The arrays of ``frames.npz`` the completion rule reads (``t``, ``collided``,
    ``bracket_length``, ``collision_length``), from a dict (returned as it is), the file
    or a design folder (its ``sim/frames.npz``)."""
    if isinstance(frames, dict):
        return frames
    p = Path(frames)
    if p.is_dir():
        p = p / "sim" / "frames.npz"
    with np.load(p, allow_pickle=False) as z:
        return {k: z[k] for k in ("t", "collided", "bracket_length", "collision_length")
                if k in z.files}


def _checked_collided(collided, t) -> np.ndarray:
    """``collided`` as (n_frames, n_cells, 4) bool matching the frame times ``t``."""
    c = np.asarray(collided).astype(bool)
    if c.ndim != 3 or c.shape[2] != 4 or c.shape[0] != t.shape[0]:
        raise InputError(f"collided has shape {c.shape}, expected (n_frames={len(t)}, "
                         "n_cells, 4)", fix="pass frames.npz's 't' and 'collided'")
    return c


def _closed(collided, bracket_length, collision_length, tol_mm, n_frames):
    """Springs at their bumpers under the clearance rule: (n_frames, n_cells, 4) bool."""
    if bracket_length is None or collision_length is None:
        return collided
    gap = (np.asarray(bracket_length, float)[:n_frames]
           - np.asarray(collision_length, float)[None])
    return collided | (gap <= tol_mm)


def never_due(t_done, t_star, t_end: float) -> np.ndarray:
    """Unit cells asked to finish by ``t_end`` that never complete: the simulation check's
    WARN (and, above ``ReportThresholds.incomplete_fail_fraction``, FAIL) and what the
    refinement minimises first.  Clamped cells count: an infeasible time is no excuse for
    a cell that stays open.

    Parameters
    ----------
    t_done : (n,) float, s -- :func:`completion_times` (NaN = never)
    t_star : (n,) float, s -- programmed times
    t_end : float, s -- last simulated time

    Returns
    -------
    (n,) bool
    """
    return ~np.isfinite(np.asarray(t_done, float)) & (np.asarray(t_star, float) <= float(t_end))


def open_layers(frames, tol_mm: float = UNIT_CELL.clearance) -> np.ndarray:
    """Layers of every unit cell still open in the last frame, by the clearance rule of
    :func:`completion_times`: a layer is open when one of its two bracket springs is
    neither collided nor within ``tol_mm`` of its bumper contact length.

    Parameters
    ----------
    frames : dict or path-like
        ``frames.npz`` content, the file or a design folder
        (:func:`read_completion_frames`).
    tol_mm : float, mm

    Returns
    -------
    open : (n_cells, 2) bool -- (top, bottom)
    """
    frames = read_completion_frames(frames)
    t = np.asarray(frames["t"], float)
    c = _checked_collided(frames["collided"], t)
    if len(t) == 0:
        raise InputError("frames.npz has no frame", fix="simulate the design first")
    c = _closed(c, frames.get("bracket_length"), frames.get("collision_length"), tol_mm,
                len(t))[-1]
    return ~np.column_stack([c[:, 0] & c[:, 1], c[:, 2] & c[:, 3]])


# --------------------------------------------------------------------------------------------
# cylinder geometry
# --------------------------------------------------------------------------------------------

def cylinder_sdf(X, center, axis, radius=UNIT_CELL.base_r, half_height=UNIT_CELL.layer_h):
    """Signed distance from points to solid cylinders (negative inside).

    Parameters
    ----------
    X : (..., 3) float, mm
        Query points.
    center, axis : (..., 3) float
        Cylinder centres (mm) and unit axes, broadcast against ``X``.
    radius, half_height : float, mm

    Returns
    -------
    d : (...) float, mm
        Exact Euclidean signed distance to the cylinder surface.
    """
    v = np.asarray(X, float) - center
    ax = np.einsum("...k,...k->...", v, axis)
    radial = np.linalg.norm(v - ax[..., None] * axis, axis=-1)
    dx = radial - radius
    dz = np.abs(ax) - half_height
    outside = np.hypot(np.maximum(dx, 0.0), np.maximum(dz, 0.0))
    inside = np.minimum(np.maximum(dx, dz), 0.0)
    return outside + inside


def cylinder_samples(radius=UNIT_CELL.base_r, half_height=UNIT_CELL.layer_h, n_around=24):
    """Surface sample points of a z-axis cylinder centred at the origin.

    Rims and side rings (5 heights), both caps (centre and a ring at r/2).

    Returns
    -------
    S : (m, 3) float, mm
    """
    a = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    ring = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    pts = []
    for z in np.linspace(-half_height, half_height, 5):
        pts.append(radius * ring + [0.0, 0.0, z])
    for z in (-half_height, half_height):
        pts.append(0.5 * radius * ring[::2] + [0.0, 0.0, z])
        pts.append(np.array([[0.0, 0.0, z]]))
    return np.concatenate(pts, axis=0)


def _pair_penetration(ci, Ri, cj, Rj, samples, radius, half_height):
    """Penetration depth and deepest point of cylinder pairs (i, j), both ways.

    Parameters
    ----------
    ci, cj : (p, 3) float, mm
    Ri, Rj : (p, 3, 3) float
    samples : (m, 3) float, mm — template surface samples

    Returns
    -------
    clearance : (p,) float, mm
        Min signed distance of one cylinder's samples to the other (negative =
        penetration depth, positive = an upper bound of the gap).
    point : (p, 3) float, mm
        The sample achieving it (the contact / deepest point).
    """
    Sj = cj[:, None, :] + np.einsum("pab,mb->pma", Rj, samples)
    Si = ci[:, None, :] + np.einsum("pab,mb->pma", Ri, samples)
    dj = cylinder_sdf(Sj, ci[:, None, :], Ri[:, None, :, 2], radius, half_height)
    di = cylinder_sdf(Si, cj[:, None, :], Rj[:, None, :, 2], radius, half_height)
    kj = np.argmin(dj, axis=1)
    ki = np.argmin(di, axis=1)
    r = np.arange(len(ci))
    mj, mi = dj[r, kj], di[r, ki]
    use_j = mj <= mi
    clearance = np.where(use_j, mj, mi)
    point = np.where(use_j[:, None], Sj[r, kj], Si[r, ki])
    return clearance, point


# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------

@dataclass
class CollisionResult:
    """Collisions found along a morph.

    Attributes
    ----------
    pairs : (k, 2) int
        Colliding pairs (base ids for base/base; (membrane vertex, base) for membrane/base).
    first_frame : (k,) int
        First frame of each pair's collision.
    first_time : (k,) float, s
    depth : (k,) float, mm
        Largest penetration depth of the pair over all frames.
    point : (k, 3) float, mm
        Deepest point at the first frame (simulation frame coordinates).
    min_clearance : (n_frames,) float, mm
        Smallest signed clearance among checked pairs per frame (inf when no pair was near).
    n_colliding : (n_frames,) int
        Number of colliding pairs per frame.
    """

    kind: str
    pairs: np.ndarray
    first_frame: np.ndarray
    first_time: np.ndarray
    depth: np.ndarray
    point: np.ndarray
    min_clearance: np.ndarray
    n_colliding: np.ndarray
    tol: float
    extra: dict = field(default_factory=dict)

    @property
    def count(self) -> int:
        return int(len(self.pairs))

    def first(self):
        """The earliest event as a dict (``None`` when clean)."""
        if not self.count:
            return None
        k = int(np.lexsort((-self.depth, self.first_frame))[0])
        return {"pair": [int(x) for x in self.pairs[k]], "frame": int(self.first_frame[k]),
                "time_s": float(self.first_time[k]), "depth_mm": float(self.depth[k]),
                "point_mm": [float(x) for x in self.point[k]]}

    def summary(self, limit=20) -> dict:
        order = np.lexsort((-self.depth, self.first_frame))[:limit]
        fin = self.min_clearance[np.isfinite(self.min_clearance)]
        return {
            "kind": self.kind,
            "count": self.count,
            "tolerance_mm": self.tol,
            "first": self.first(),
            "max_depth_mm": float(self.depth.max()) if self.count else 0.0,
            "min_clearance_mm": float(fin.min()) if fin.size else None,
            "events": [{"pair": [int(x) for x in self.pairs[k]],
                        "frame": int(self.first_frame[k]),
                        "time_s": float(self.first_time[k]),
                        "depth_mm": float(self.depth[k])} for k in order],
            **self.extra,
        }


def _collect(kind, events, n_frames, t, min_clear, n_coll, tol, extra=None):
    """Merge per-frame events ``(frame, a, b, depth, point)`` into a :class:`CollisionResult`."""
    if events:
        fr = np.concatenate([e[0] for e in events])
        ab = np.concatenate([e[1] for e in events])
        dep = np.concatenate([e[2] for e in events])
        pt = np.concatenate([e[3] for e in events])
        keys, inv = np.unique(ab, axis=0, return_inverse=True)
        inv = inv.ravel()
        order = np.lexsort((fr, inv))           # by pair, then frame
        first_idx = order[np.r_[True, inv[order][1:] != inv[order][:-1]]]
        depth = np.zeros(len(keys))
        np.maximum.at(depth, inv, dep)
        pairs = ab[first_idx]
        first_frame = fr[first_idx]
        point = pt[first_idx]
        depth = depth[inv[first_idx]]
    else:
        pairs = np.zeros((0, 2), int)
        first_frame = np.zeros(0, int)
        depth = np.zeros(0)
        point = np.zeros((0, 3))
    return CollisionResult(kind=kind, pairs=pairs, first_frame=first_frame,
                           first_time=np.asarray(t, float)[first_frame], depth=depth,
                           point=point, min_clearance=min_clear, n_colliding=n_coll, tol=tol,
                           extra=extra or {})


def _check_poses(base_center, base_rotation):
    C = np.asarray(base_center, float)
    R = np.asarray(base_rotation, float)
    if C.ndim != 3 or C.shape[2] != 3 or R.shape != C.shape[:2] + (3, 3):
        raise InputError(
            f"base_center {C.shape} / base_rotation {R.shape}: expected (n_frames, n_bases, 3) "
            "and (n_frames, n_bases, 3, 3)",
            fix="pass the arrays of frames.npz as written by sim.model.simulate.")
    return C, R


# --------------------------------------------------------------------------------------------
# base vs base
# --------------------------------------------------------------------------------------------

def base_collisions(base_center, base_rotation, neighbour_pairs, *, t=None,
                    tol=0.1, radius=UNIT_CELL.base_r, half_height=UNIT_CELL.layer_h,
                    clearance_margin=2.0, frames=None):
    """Find overlapping non-neighbouring bases in every frame.

    Parameters
    ----------
    base_center : (n_frames, n_bases, 3) float, mm
    base_rotation : (n_frames, n_bases, 3, 3) float
        Flat pose -> current pose; column 2 is the base axis (flat +z).
    neighbour_pairs : (n_cells, 2) int
        Bases sharing a unit cell (``cells.csv`` base_a, base_b): never checked.
    t : (n_frames,) float, s, optional
        Frame times (default: frame indices).
    tol : float, mm
        A pair collides when its penetration depth exceeds ``tol``.
    radius, half_height : float, mm
        Collision cylinder (default 2 mm and 2.3 mm: Ø 4 x 4.6 mm).
    clearance_margin : float, mm
        Pairs up to this gap are also evaluated, to report the closest approach.
    frames : (k,) int, optional
        Frames to check (default all).

    Returns
    -------
    CollisionResult
        ``kind = "base-base"``; ``pairs`` are base ids (i < j).
    """
    C, R = _check_poses(base_center, base_rotation)
    n_frames, n_bases = C.shape[:2]
    t = np.arange(n_frames, dtype=float) if t is None else np.asarray(t, float)
    nb = np.asarray(neighbour_pairs, dtype=np.int64).reshape(-1, 2)
    if nb.size and (nb.min() < 0 or nb.max() >= n_bases):
        raise InputError(f"neighbour pair ids outside 0..{n_bases - 1}",
                         fix="cells.csv base_a/base_b must index bases.csv rows.")
    nb_keys = np.sort(nb, axis=1)
    nb_code = np.unique(nb_keys[:, 0] * n_bases + nb_keys[:, 1])
    samples = cylinder_samples(radius, half_height)
    reach = 2.0 * np.hypot(radius, half_height) + clearance_margin
    min_clear = np.full(n_frames, np.inf)
    n_coll = np.zeros(n_frames, int)
    events = []
    frames = range(n_frames) if frames is None else np.asarray(frames, int)
    for f in frames:
        pairs = cKDTree(C[f]).query_pairs(reach, output_type="ndarray")
        if not len(pairs):
            continue
        pairs = np.sort(pairs, axis=1)
        code = pairs[:, 0] * n_bases + pairs[:, 1]
        pairs = pairs[~np.isin(code, nb_code, assume_unique=False)]
        if not len(pairs):
            continue
        i, j = pairs[:, 0], pairs[:, 1]
        clr, pt = _pair_penetration(C[f, i], R[f, i], C[f, j], R[f, j], samples,
                                    radius, half_height)
        min_clear[f] = clr.min()
        hit = clr < -tol
        n_coll[f] = int(hit.sum())
        if hit.any():
            events.append((np.full(hit.sum(), f), pairs[hit], -clr[hit], pt[hit]))
    return _collect("base-base", events, n_frames, t, min_clear, n_coll, tol,
                    {"radius_mm": radius, "height_mm": 2 * half_height, "reach_mm": reach})


# --------------------------------------------------------------------------------------------
# membrane vs base
# --------------------------------------------------------------------------------------------

def membrane_collisions(base_center, base_rotation, membrane_vertices, *, t=None, tol=0.1,
                        local_radius=None, radius=UNIT_CELL.base_r, half_height=UNIT_CELL.layer_h,
                        frames=None, flat_vertices=None, flat_centers=None):
    """Find membrane vertices inside bases that were far from them in the flat layout.

    Parameters
    ----------
    base_center : (n_frames, n_bases, 3) float, mm
    base_rotation : (n_frames, n_bases, 3, 3) float
    membrane_vertices : (n_frames, n_mem, 3) float, mm
    t : (n_frames,) float, s, optional
    tol : float, mm
        A vertex collides when it is deeper than ``tol`` inside a base.
    local_radius : float, mm
        Flat distance (vertex to base centre) under which the pair is never
        checked; default ``base_r + max_cell_length`` = 11.5 mm: the vertex
        lies in a unit cell of that base or of a neighbour, where contact with
        the bumpers and the base rim is part of the design.
    radius, half_height : float, mm
    frames : (k,) int, optional
    flat_vertices : (n_mem, 3) float, mm, optional
    flat_centers : (n_bases, 3) float, mm, optional
        Flat layout of the membrane vertices and base centres (frames.npz
        ``flat_membrane_vertices`` / ``flat_base_center``), which defines the
        "local" pairs; default: frame 0.

    Returns
    -------
    CollisionResult
        ``kind = "membrane-base"``; ``pairs`` are (membrane vertex, base id).
    """
    C, R = _check_poses(base_center, base_rotation)
    M = np.asarray(membrane_vertices, float)
    n_frames, n_bases = C.shape[:2]
    if M.ndim != 3 or M.shape[0] != n_frames or M.shape[2] != 3:
        raise InputError(f"membrane_vertices has shape {M.shape}, expected "
                         f"(n_frames={n_frames}, n_mem, 3)",
                         fix="pass the membrane_vertices array of frames.npz.")
    t = np.arange(n_frames, dtype=float) if t is None else np.asarray(t, float)
    if local_radius is None:
        local_radius = radius + UNIT_CELL.max_cell_length
    n_mem = M.shape[1]
    fv = M[0] if flat_vertices is None else np.asarray(flat_vertices, float)
    fc = C[0] if flat_centers is None else np.asarray(flat_centers, float)
    if fv.shape != (n_mem, 3) or fc.shape != (n_bases, 3):
        raise InputError(f"flat_vertices {fv.shape} / flat_centers {fc.shape}: expected "
                         f"({n_mem}, 3) and ({n_bases}, 3)",
                         fix="pass frames.npz flat_membrane_vertices and flat_base_center")
    flat_tree = cKDTree(fv[:, :2])
    # local (vertex, base) pairs in the flat layout, encoded as v * n_bases + b
    local = flat_tree.query_ball_point(fc[:, :2], local_radius)
    local_code = np.unique(np.concatenate(
        [np.asarray(vs, dtype=np.int64) * n_bases + b for b, vs in enumerate(local)]
        + [np.zeros(0, np.int64)]))
    reach = np.hypot(radius, half_height)
    min_clear = np.full(n_frames, np.inf)
    n_coll = np.zeros(n_frames, int)
    events = []
    frames = range(n_frames) if frames is None else np.asarray(frames, int)
    for f in frames:
        near = cKDTree(M[f]).query_ball_point(C[f], reach)
        lens = np.fromiter((len(x) for x in near), int, n_bases)
        if not lens.sum():
            continue
        b = np.repeat(np.arange(n_bases), lens)
        v = np.concatenate([np.asarray(x, dtype=np.int64) for x in near if len(x)])
        code = v * n_bases + b
        keep = ~np.isin(code, local_code)
        b, v = b[keep], v[keep]
        if not len(b):
            continue
        d = cylinder_sdf(M[f, v], C[f, b], R[f, b, :, 2], radius, half_height)
        min_clear[f] = d.min()
        hit = d < -tol
        n_coll[f] = int(hit.sum())
        if hit.any():
            events.append((np.full(hit.sum(), f), np.stack([v[hit], b[hit]], axis=1),
                           -d[hit], M[f, v[hit]]))
    return _collect("membrane-base", events, n_frames, t, min_clear, n_coll, tol,
                    {"local_radius_mm": float(local_radius), "n_membrane_vertices": int(n_mem)})


__all__ = ["completion_times", "read_completion_frames",
           "never_due", "open_layers", "cylinder_sdf", "cylinder_samples", "CollisionResult",
           "base_collisions", "membrane_collisions"]
