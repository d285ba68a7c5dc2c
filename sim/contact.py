"""Barrier contact between bases that are not neighbours (issue #18, ``PhysicsOptions.contact``).

The reference simulator only reports overlaps (:mod:`sim.collisions`); a shell whose far-apart
regions meet (interwoven designs, tight folds) passes through itself.  With ``contact`` on,
every base is a closed prism (a regular ``contact_sides``-gon circumscribed about the base
disc of radius ``base_r``, as thick as both layers, ``2 layer_h``) that moves with its base, so
that prisms kept apart imply discs kept apart (the cylinders :mod:`sim.collisions` checks), and the IPC barrier of the IPC
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

Cost: a KD-tree of the base centres finds the pairs of non-neighbours whose prisms can be
within ``dhat`` (centre distance below the prisms' circumscribed diameter plus ``dhat``); only
those bases enter the ipctk mesh, so a shell with no close pairs pays one KD-tree query per
evaluation.  The contact Hessian couples non-neighbouring bases, outside the fixed sparsity
pattern; it is added as a separate matrix and CHOLMOD re-analyses the pattern when the set of
contacts changes.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from pysolver.errors import InputError


def _ipctk():
    try:
        import ipctk
    except ImportError:  # soft dependency
        raise InputError("physics effect 'contact' needs the IPC Toolkit's Python bindings",
                         fix="pip install ipctk") from None
    # one thread, as every solve here (sim.solver): on 2 cores its TBB pool doubled the CPU
    # time and cost wall time (contact on the 575-base bench: 42 s wall, 64 s CPU)
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
        a, b = model.cell_bases[:, 0], model.cell_bases[:, 1]
        self.neighbour = {(int(min(x, y)), int(max(x, y))) for x, y in zip(a, b, strict=True)}
        self.barrier = self.ipc.BarrierPotential(self.dhat, self.kappa)
        self.n_dof = model.n_dof
        self.last_pairs = 0
        # one collision mesh for every pair (two prisms): the topology is fixed, the rest
        # positions only seed ipctk's adjacency, so it is built once and reused
        F = np.r_[self.faces, self.faces + self.nv].astype(np.int32)
        X = np.r_[self.local, self.local + [4 * self.reach, 0.0, 0.0]]
        self._pair_mesh = self.ipc.CollisionMesh(np.asfortranarray(X), self.ipc.edges(F), F)

    # -- geometry --------------------------------------------------------------------------
    def close_pairs(self, c, reach=None) -> np.ndarray:
        """(k, 2) int: non-neighbouring base pairs with centres closer than ``reach`` (mm)."""
        from scipy.spatial import cKDTree

        pairs = cKDTree(c).query_pairs(self.reach if reach is None else reach,
                                       output_type="ndarray")
        if len(pairs) == 0:
            return pairs.reshape(0, 2)
        keep = [tuple(p) not in self.neighbour for p in np.sort(pairs, axis=1).tolist()]
        return pairs[np.asarray(keep, bool)]

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
        pairs = self.close_pairs(state.c)
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
        """Largest collision-free multiple of the step ``p`` (up to ``alpha_max``), times 0.8.

        The pairs of non-neighbours whose prisms can meet during the step (centre distance
        below ``reach`` plus twice the largest point motion of the step) are swept linearly
        from ``state`` to ``state.moved(p, alpha_max)`` and checked by ipctk's continuous
        collision detection (the rotation's path is approximated by the chord; the 0.8
        factor, as in IPC, keeps a margin).
        """
        m = self.m
        body = np.asarray(p[: 6 * m]).reshape(m, 6) * alpha_max
        r_out = float(np.linalg.norm(self.local[0]))
        # per base: an upper bound of how far any of its prism points moves in the step
        motion = np.linalg.norm(body[:, :3], axis=1) + np.linalg.norm(body[:, 3:], axis=1) * r_out
        pairs = self.close_pairs(state.c, self.reach + 2 * motion.max(initial=0.0))
        if len(pairs):
            gap = np.linalg.norm(state.c[pairs[:, 0]] - state.c[pairs[:, 1]], axis=1)
            pairs = pairs[gap < self.reach + motion[pairs[:, 0]] + motion[pairs[:, 1]]]
        if len(pairs) == 0:
            return alpha_max
        s1 = state.moved(p, alpha_max)
        t = 1.0
        for pq in pairs:
            X0, _, mesh = self._mesh(pq, state.c, state.R)
            X1, _, _ = self._mesh(pq, s1.c, s1.R)
            t = min(t, self.ipc.compute_collision_free_stepsize(mesh, np.asfortranarray(X0),
                                                                np.asfortranarray(X1)))
        return alpha_max if t >= 1.0 else 0.8 * t * alpha_max

    def min_distance(self, state) -> float:
        """Smallest distance (mm) between non-neighbouring prisms closer than ``reach``; inf
        when none is."""
        d = np.inf
        for pq in self.close_pairs(state.c):
            X, _, mesh = self._mesh(pq, state.c, state.R)
            Xf = np.asfortranarray(X)
            col = self.ipc.NormalCollisions()
            col.build(mesh, Xf, self.reach)
            if not col.empty():
                d = min(d, float(np.sqrt(col.compute_minimum_distance(mesh, Xf))))
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


__all__ = ["BaseContact", "prism"]
