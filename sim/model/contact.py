"""Barrier contact between bases that are not neighbours (issue #18, ``PhysicsOptions.contact``).

The reference simulator only reports overlaps (:mod:`sim.model.collisions`); a shell whose far-apart
regions meet (interwoven designs, tight folds) passes through itself.  With ``contact`` on,
every base is a closed prism (a regular ``contact_sides``-gon circumscribed about the base
disc of radius ``base_r``, as thick as both layers, ``2 layer_h``) that moves with its base, so
that prisms kept apart imply discs kept apart (the cylinders :mod:`sim.model.collisions`
checks), and the IPC barrier of the IPC
Toolkit (``ipctk``, Li et al. 2020, "Incremental Potential Contact") keeps non-neighbouring
prisms apart:

* energy ``kappa * sum_k b(d_k)``, ``b(d) = -(d - dhat)^2 ln(d / dhat)`` for ``d < dhat``
  over the vertex-face and edge-edge pairs closer than ``dhat`` (``contact_dhat_mm``), with
  ``kappa = contact_stiffness`` (N/mm);
* it goes to infinity as two prisms touch, and every Newton step is limited to the
  collision-free fraction of the step found by ipctk's continuous collision detection
  (:meth:`BaseContact.step_limit`, with a 0.8 safety factor as in IPC); since a rotating
  base moves on arcs, not on the chords the CCD sweeps, a trial state in which two close
  prisms intersect also gets infinite energy, so no configuration the solver accepts has
  two prisms through each other.

Neighbouring bases (sharing a unit cell) are not paired: their bumpers keep them at least
``2 min_bumper`` apart, and their contact is the bumper spring.  Membrane and brackets are not
part of the contact mesh (the membrane lies inside the prisms at the bases; the brackets are
inside the cells).

Cost.  The broad phase is a Verlet list: a KD-tree of the base centres lists the pairs of
non-neighbours whose centres are within the prisms' circumscribed diameter plus ``dhat`` plus
twice a skin (``SIM.contact_skin_mm``), and the list is reused until some centre has moved a
skin from where it was built.  Each listed pair then gets a separating-axis lower bound of its
distance, the centre distance less both prisms' extents along the line of centres
(:func:`gap_lower_bound`).  Only pairs whose bound is below ``dhat`` enter ipctk for the
barrier (the barrier of the others is exactly zero), and only pairs whose bound is below the
step's largest point motions enter the continuous collision detection; a shell with no close
pairs pays a few vector operations per evaluation.  The contact Hessian couples
non-neighbouring bases, outside the fixed sparsity pattern; it is added as a separate matrix
and CHOLMOD re-analyses the pattern when the set of contacts changes.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from pysolver.errors import InputError
from pysolver.params import NEWTON, SIM


def _ipctk():
    try:
        import ipctk  # optional: IPC contact only with --physics contact
    except ImportError:  # soft dependency
        raise InputError("physics effect 'contact' needs the IPC Toolkit's Python bindings",
                         fix="pip install ipctk") from None
    # one thread, as every solve here (pysolver.mechanics.solver): on 2 cores its TBB pool
    # doubled the CPU time and cost wall time (contact on the 575-base bench: 42 s wall, 64 s CPU)
    ipctk.set_num_threads(1)
    return ipctk


def prism(radius: float, half_height: float, sides: int):
    """Closed prism around a base: vertices ``(2 sides, 3)`` (flat frame, centred) and outward
    CCW faces ``(4 sides - 4, 3)``."""
    a = 2 * np.pi * np.arange(sides) / sides
    ring = np.c_[radius * np.cos(a), radius * np.sin(a)]
    V = np.r_[np.c_[ring, np.full(sides, half_height)], np.c_[ring, np.full(sides, -half_height)]]
    k = np.arange(sides)
    k1 = (k + 1) % sides
    top = np.c_[np.zeros(sides - 2, int), np.arange(1, sides - 1), np.arange(2, sides)]
    bot = sides + top[:, [0, 2, 1]]
    side = np.r_[np.c_[k, sides + k, sides + k1], np.c_[k, sides + k1, k1]]
    return V, np.r_[top, bot, side].astype(np.int32)


def gap_lower_bound(c, axis, pairs, radius: float, half_height: float) -> np.ndarray:
    """Lower bound of the distance between the prisms of base pairs (separating axis).

    Each prism lies in the cylinder of ``radius`` and ``half_height`` about its base's axis,
    whose extent along a unit direction ``u`` is ``radius sqrt(1 - (n.u)^2) + half_height
    |n.u|``.  Along the line of centres ``u``, two convex bodies are at least the centre
    distance less both extents apart (negative: they may touch).

    Parameters
    ----------
    c : (m, 3) float, mm
        Base centres.
    axis : (m, 3) float
        Unit prism axes (the bases' normals, ``R[:, :, 2]``).
    pairs : (k, 2) int
        Base pairs.
    radius, half_height : float, mm
        Prism circumradius in the base plane and half thickness.

    Returns
    -------
    (k,) float, mm
    """
    d = c[pairs[:, 1]] - c[pairs[:, 0]]
    D = np.linalg.norm(d, axis=1)
    u = d / np.maximum(D, np.finfo(float).tiny)[:, None]
    ext = 0.0
    for k in (0, 1):
        nu = np.abs(np.einsum("ki,ki->k", axis[pairs[:, k]], u))
        ext = ext + radius * np.sqrt(np.maximum(1.0 - nu * nu, 0.0)) + half_height * nu
    return D - ext


class BaseContact:
    """IPC barrier between non-neighbouring base prisms of a :class:`ShellModel`.

    Parameters
    ----------
    model : ShellModel
    opts : PhysicsOptions
        ``contact_dhat_mm`` (mm), ``contact_stiffness`` (N/mm), ``contact_sides``.
    """

    def __init__(self, model, opts):
        self.ipc = _ipctk()
        u = model.unit
        self.m = model.n_bases
        # circumscribed: an inscribed polygon would let two discs overlap by up to
        # 2 base_r (1 - cos(pi / sides)) (0.3 mm for an octagon) while the prisms only touch
        radius = u.base_r / math.cos(math.pi / opts.contact_sides)
        self.local, self.faces = prism(radius, u.layer_h, opts.contact_sides)
        self.nv = len(self.local)
        self.dhat = float(opts.contact_dhat_mm)
        self.kappa = float(opts.contact_stiffness)
        self.reach = 2 * math.hypot(radius, u.layer_h) + self.dhat
        self.radius, self.half_height = float(radius), float(u.layer_h)
        self.r_out = math.hypot(self.radius, self.half_height)  # every prism vertex's radius
        a, b = model.cell_bases[:, 0], model.cell_bases[:, 1]
        self.neighbour = {(int(min(x, y)), int(max(x, y))) for x, y in zip(a, b, strict=True)}
        self.skin = float(SIM.contact_skin_mm)
        self._verlet = None  # (centres (m, 3) mm, list radius mm, pairs (k, 2)) of the list
        self.barrier = self.ipc.BarrierPotential(self.dhat, self.kappa)
        self.n_dof = model.n_dof
        self.last_pairs = 0
        # one collision mesh for every pair (two prisms): the topology is fixed, the rest
        # positions only seed ipctk's adjacency, so it is built once and reused
        F = np.r_[self.faces, self.faces + self.nv].astype(np.int32)
        X = np.r_[self.local, self.local + [4 * self.reach, 0.0, 0.0]]
        self._pair_mesh = self.ipc.CollisionMesh(np.asfortranarray(X), self.ipc.edges(F), F)

    # -- geometry --------------------------------------------------------------------------
    @property
    def neighbour(self) -> set:
        """Pairs ``(p, q)``, ``p < q``, of bases sharing a unit cell (never in contact)."""
        return self._neighbour

    @neighbour.setter
    def neighbour(self, pairs) -> None:
        self._neighbour = set(pairs)
        keys = [p * self.m + q for p, q in self._neighbour]
        self._neighbour_keys = np.sort(np.asarray(keys, dtype=np.int64))
        self._verlet = None

    def _non_neighbours(self, pairs) -> np.ndarray:
        """The rows of ``pairs`` (k, 2) int that are not neighbours."""
        pairs = np.sort(pairs.reshape(-1, 2), axis=1)
        keys = pairs[:, 0].astype(np.int64) * self.m + pairs[:, 1]
        return pairs[~np.isin(keys, self._neighbour_keys, assume_unique=False)]

    def close_pairs(self, c, reach=None) -> np.ndarray:
        """(k, 2) int: non-neighbouring base pairs with centres closer than ``reach`` (mm,
        default ``self.reach``, the circumscribed spheres plus ``dhat``).

        Served from the Verlet list while every centre is within the skin of where the list
        was built (a pair closer than ``reach`` now was closer than ``reach`` plus twice the
        largest displacement then), else from a new list ``2 skin`` wider than ``reach``."""
        reach = self.reach if reach is None else float(reach)
        v = self._verlet
        if v is not None:
            moved = np.sqrt(np.einsum("ij,ij->i", c - v[0], c - v[0]).max(initial=0.0))
            if reach + 2 * moved > v[1]:
                v = None
        if v is None:
            radius = reach + 2 * self.skin
            pairs = cKDTree(c).query_pairs(radius, output_type="ndarray")
            v = self._verlet = (np.array(c, copy=True), radius, self._non_neighbours(pairs))
        pairs = v[2]
        if len(pairs) == 0:
            return pairs
        d = c[pairs[:, 1]] - c[pairs[:, 0]]
        return pairs[np.einsum("ij,ij->i", d, d) < reach * reach]

    def gap_bound(self, state, pairs) -> np.ndarray:
        """(k,) float, mm: lower bound of the distance of the prisms of ``pairs`` at ``state``
        (:func:`gap_lower_bound`)."""
        return gap_lower_bound(state.c, state.R[:, :, 2], pairs, self.radius, self.half_height)

    def barrier_pairs(self, state) -> np.ndarray:
        """(k, 2) int: the non-neighbouring pairs whose prisms may be within ``dhat``; the
        barrier of every other pair is exactly zero."""
        pairs = self.close_pairs(state.c)
        return pairs[self.gap_bound(state, pairs) < self.dhat] if len(pairs) else pairs

    def _mesh(self, bases, c, R):
        """Collision mesh of two (or more) bases: vertices (nb * nv, 3), rotated offsets, and
        the ipctk mesh.  Called per pair of non-neighbours, so no pair filter is needed:
        primitives of one prism that share no vertex are >= 1 mm apart, beyond ``dhat``.
        (A Python ``can_collide`` filter would serialise ipctk's parallel broad phase on the
        GIL; per-pair meshes avoid it.)"""
        v = np.einsum("bij,kj->bki", R[bases], self.local)  # (nb, nv, 3)
        X = (c[bases][:, None, :] + v).reshape(-1, 3)
        if len(bases) == 2:
            return X, v.reshape(-1, 3), self._pair_mesh
        F = (self.faces[None] + self.nv * np.arange(len(bases))[:, None, None]).reshape(-1, 3)
        F = np.ascontiguousarray(F, dtype=np.int32)
        mesh = self.ipc.CollisionMesh(np.asfortranarray(X), self.ipc.edges(F), F)
        return X, v.reshape(-1, 3), mesh

    def _jacobian(self, v, nb):
        """Sparse (3 nv, 6 nb) map from (centre, rotation) of each base to its points,
        ``J = [I, -[v]x]`` per point (theta = 0)."""
        nv = len(v)
        owner = np.repeat(np.arange(nb), self.nv)
        rows = np.repeat(np.arange(3 * nv), 6)
        cols = np.empty((nv, 3, 6), dtype=np.int64)
        vals = np.zeros((nv, 3, 6))
        for i in range(3):
            cols[:, i, :] = 6 * owner[:, None] + np.arange(6)
            vals[:, i, i] = 1.0
        vx, vy, vz = v[:, 0], v[:, 1], v[:, 2]
        vals[:, 0, 4], vals[:, 0, 5] = vz, -vy
        vals[:, 1, 3], vals[:, 1, 5] = -vz, vx
        vals[:, 2, 3], vals[:, 2, 4] = vy, -vx
        return sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(3 * nv, 6 * nb)), owner

    # -- energy ----------------------------------------------------------------------------
    def evaluate(self, state, hessian: bool):
        """Barrier energy (N mm), reduced gradient (n_dof,) and lower-triangle Hessian (CSC,
        n_dof x n_dof) or None; ``(0.0, None, None)`` when no pair is close."""
        pairs = self.barrier_pairs(state)
        self.last_pairs = len(pairs)
        if len(pairs) == 0:
            return 0.0, None, None
        E = 0.0
        g = np.zeros(self.n_dof)
        rows, cols, vals = [], [], []
        active = False
        for pq in pairs:
            X, v, mesh = self._mesh(pq, state.c, state.R)
            Xf = np.asfortranarray(X)
            col = self.ipc.NormalCollisions()
            col.build(mesh, Xf, self.dhat)
            if col.empty():
                continue
            active = True
            if self.ipc.has_intersections(mesh, Xf):
                # a trial state through a prism (the step limit sweeps chords, the rotation
                # moves on arcs): infinite energy, the line search backs off
                return np.inf, g, None
            E += float(self.barrier(col, mesh, Xf))
            gp = np.asarray(self.barrier.gradient(col, mesh, Xf)).reshape(-1, 3)
            J, owner = self._jacobian(v, 2)
            dofs = (6 * np.asarray(pq)[:, None] + np.arange(6)).ravel()
            g[dofs] += J.T @ gp.ravel()
            if not hessian or not np.isfinite(E):
                continue
            Hr = (J.T @ sp.csr_matrix(self.barrier.hessian(col, mesh, Xf)) @ J).toarray()
            # second-order term of the rotation: sum_p 0.5 (g v^T + v g^T) - (g . v) I
            gv = gp[:, :, None] * v[:, None, :]
            term = 0.5 * (gv + np.transpose(gv, (0, 2, 1))) - np.einsum(
                "ni,ni->n", gp, v)[:, None, None] * np.eye(3)
            for k in range(2):
                Hr[6 * k + 3:6 * k + 6, 6 * k + 3:6 * k + 6] += term[owner == k].sum(axis=0)
            r, cc = np.nonzero(np.ones_like(Hr, dtype=bool))
            keep = dofs[r] >= dofs[cc]
            rows.append(dofs[r][keep])
            cols.append(dofs[cc][keep])
            vals.append(0.5 * (Hr + Hr.T)[r, cc][keep])
        if not active:
            return 0.0, None, None
        if not hessian or not np.isfinite(E):
            return E, g, None
        H = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(self.n_dof, self.n_dof))
        H.sum_duplicates()
        return E, g, H

    def step_limit(self, state, p, alpha_max: float) -> float:
        """Largest collision-free multiple of the step ``p`` (up to ``alpha_max``), times
        ``NEWTON.ccd_safety``.

        Every prism point of base ``b`` moves by at most ``motion_b`` (its translation plus
        its rotation angle times the vertex radius) along the linear sweep from ``state`` to
        ``state.moved(p, alpha_max)``, so a pair whose distance bound
        (:meth:`gap_bound`) exceeds ``motion_p + motion_q`` cannot meet.  The other pairs are
        checked by ipctk's continuous collision detection (the rotation's path is
        approximated by the chord; the safety factor, as in IPC, keeps a margin).
        """
        m = self.m
        body = np.asarray(p[: 6 * m]).reshape(m, 6) * alpha_max
        # per base: an upper bound of how far any of its prism points moves in the step
        motion = (np.linalg.norm(body[:, :3], axis=1)
                  + np.linalg.norm(body[:, 3:], axis=1) * self.r_out)
        pairs = self.close_pairs(state.c, self.reach + 2 * motion.max(initial=0.0))
        if len(pairs):
            reach = motion[pairs[:, 0]] + motion[pairs[:, 1]]
            pairs = pairs[self.gap_bound(state, pairs) <= reach]
        if len(pairs) == 0:
            return alpha_max
        s1 = state.moved(p, alpha_max)
        t = 1.0
        for pq in pairs:
            X0, _, mesh = self._mesh(pq, state.c, state.R)
            X1, _, _ = self._mesh(pq, s1.c, s1.R)
            t = min(t, self.ipc.compute_collision_free_stepsize(mesh, np.asfortranarray(X0),
                                                                np.asfortranarray(X1)))
        return alpha_max if t >= 1.0 else NEWTON.ccd_safety * t * alpha_max

    def min_distance(self, state) -> float:
        """Smallest distance (mm) between non-neighbouring prisms closer than ``reach``; inf
        when none is.  Only primitives of different prisms count (with a distance cut-off
        above the prisms' own feature size, ipctk also pairs faces and vertices of one
        prism)."""
        d = np.inf
        for pq in self.close_pairs(state.c):
            X, _, mesh = self._mesh(pq, state.c, state.R)
            Xf = np.asfortranarray(X)
            col = self.ipc.NormalCollisions()
            col.build(mesh, Xf, self.reach)
            E, F = mesh.edges, mesh.faces
            for kind in (col.vv_collisions, col.ev_collisions, col.ee_collisions,
                         col.fv_collisions):
                for cc in kind:
                    ids = np.asarray(cc.vertex_ids(E, F))
                    if len(np.unique(ids[ids >= 0] // self.nv)) > 1:
                        d = min(d, float(np.sqrt(cc.compute_distance(Xf, E, F))))
        return d

    def intersecting_pair(self, state, pq) -> bool:
        """The prisms of bases ``pq = (p, q)`` intersect."""
        X, _, mesh = self._mesh(np.asarray(pq), state.c, state.R)
        return bool(self.ipc.has_intersections(mesh, np.asfortranarray(X)))

    def intersecting(self, state) -> bool:
        """Any two non-neighbouring prisms intersect."""
        for pq in self.close_pairs(state.c):
            X, _, mesh = self._mesh(pq, state.c, state.R)
            if self.ipc.has_intersections(mesh, np.asfortranarray(X)):
                return True
        return False


__all__ = ["BaseContact", "gap_lower_bound", "prism"]
