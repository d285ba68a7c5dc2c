"""Physics beyond the reference simulator (issues #18, #32): switches, masses, weight, a plane.

Every effect is a field of :class:`pysolver.params.PhysicsOptions`; with all off
(:data:`~pysolver.params.PHYSICS_OFF`) the simulation is the reference model bit for bit, and
the simulator's default is :data:`~pysolver.params.PHYSICS_DEFAULT`.  This module holds

* :func:`parse_physics` / :func:`check_physics`: the ``--physics`` option and its validation;
* :func:`base_volumes`, :func:`membrane_vertex_masses`: printed volume of every base (mm^3)
  and lumped latex mass of every membrane vertex;
* :class:`ExternalTerms`: the energy of the weight (with or without buoyancy) and of a
  frictionless plane (tank floor in water, table when dry), with its reduced gradient and
  Hessian, added to :class:`pysolver.mechanics.energies.ShellEnergy` through its ``external`` hook.

Relaxation and the membrane's temperature (``mu`` scaled by the measured curve and by the
absolute temperature) live in the time stepper (:mod:`sim.model.simulate`); the rim margin and
the printing clearance of the bumpers in :func:`pysolver.mechanics.build_model`; they reuse
the one membrane energy and the one contact spring of :mod:`pysolver.mechanics.energies`.

Units: mm, N, s; densities in g/cm^3 = 1e-9 t/mm^3, so a volume ``V`` (mm^3) of density
``rho`` weighs ``rho * 1e-9 * V * g`` N with ``g = 9810 mm/s^2``.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np

from pysolver.errors import InputError
from pysolver.mechanics.energies import jtkj, skew
from pysolver.params import PHYSICS_DEFAULT, PHYSICS_OFF, UNIT_CELL, PhysicsOptions

DENSITY_TO_T_MM3 = 1e-9  # g/cm^3 -> t/mm^3 (mm-N-s-t units: 1 t mm/s^2 = 1 N)
FACE_DOWN = ("bottom", "top")


def check_physics(opts: PhysicsOptions) -> PhysicsOptions:
    """Validate ``opts``; returns it.  Bad values raise :class:`InputError` naming the fix."""
    if not isinstance(opts, PhysicsOptions):
        raise InputError(f"physics options must be a PhysicsOptions, got {type(opts).__name__}")
    pos = ("print_density", "water_density", "latex_density", "gravity_mm_s2",
           "ground_stiffness", "rim_margin_mm", "contact_dhat_mm", "contact_stiffness")
    for k in pos:
        v = getattr(opts, k)
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise InputError(f"physics option {k} = {v!r} must be a positive number",
                             fix=f"pass --{k.replace('_', '-')} with a value > 0")
    R = PhysicsOptions.RANGES
    for k, unit in (("stretch_to_glue_min", "minutes"), ("glue_to_water_min", "minutes"),
                    ("drying_min", "minutes"), ("water_temp_c", "deg C"),
                    ("lab_temp_c", "deg C")):
        v, (lo, hi) = getattr(opts, k), R[k]
        if not (isinstance(v, int | float) and math.isfinite(v) and lo <= v <= hi):
            raise InputError(f"physics option {k} = {v!r} must be in {lo:g}..{hi:g} {unit}",
                             fix=f"pass --{k.replace('_', '-')} in {unit}")
    lo, hi = R["rim_stretch"]
    if not (isinstance(opts.rim_stretch, int | float) and lo <= opts.rim_stretch <= hi):
        raise InputError(f"rim_stretch = {opts.rim_stretch!r} must be in [{lo:g}, {hi:g}]",
                         fix=f"pass --rim-stretch {PHYSICS_OFF.rim_stretch:g} (the margin "
                             "frozen by the glue) up to the sheet's pre-stretch")
    if opts.face_down not in FACE_DOWN:
        raise InputError(f"face_down = {opts.face_down!r} must be one of {FACE_DOWN}",
                         fix="pass --face-down bottom or --face-down top")
    for k in ("ground_points", "contact_sides"):
        v, (lo, hi) = getattr(opts, k), R[k]
        if not (isinstance(v, int) and lo <= v <= hi):
            raise InputError(f"{k} = {v!r} must be an int in {lo}..{hi}")
    gap = 2 * UNIT_CELL.min_bumper
    if opts.contact_dhat_mm >= gap:
        raise InputError(f"contact_dhat_mm = {opts.contact_dhat_mm} mm reaches neighbouring "
                         f"bases (bumpers keep them >= {gap:g} mm apart)",
                         fix=f"pass --contact-dhat-mm below {gap:g} (default "
                             f"{PHYSICS_OFF.contact_dhat_mm:g})")
    return opts


def parse_physics(spec: str | None = None, **params) -> PhysicsOptions:
    """Physics options from ``--physics clearance,gravity,...`` and parameter overrides.

    Parameters
    ----------
    spec : str, optional
        Comma-separated switches (:attr:`PhysicsOptions.SWITCHES`, ``-`` or ``_`` alike):
        exactly those effects.  ``"default"`` (alone or in the list) stands for the
        default set :data:`~pysolver.params.PHYSICS_DEFAULT`; ``None`` is the default set;
        ``"none"`` or ``""`` is the reference model (:data:`~pysolver.params.PHYSICS_OFF`);
        ``"all"`` is every implemented effect.
    **params
        Field overrides (``glue_to_water_min=30``, ``print_density=1.17``); ``None`` values
        are ignored.

    Returns
    -------
    PhysicsOptions
    """
    on = {}
    base = PHYSICS_DEFAULT if spec is None else PHYSICS_OFF
    spec = (spec or "").strip()
    if spec and spec != "none":
        names = PhysicsOptions.SWITCHES if spec == "all" else [
            s.strip().replace("-", "_") for s in spec.split(",") if s.strip()]
        for n in names:
            if n == "default":
                on.update({k: True for k in PHYSICS_DEFAULT.switched_on()})
                continue
            if n not in PhysicsOptions.SWITCHES:
                raise InputError(f"unknown physics effect {n!r}",
                                 fix="use a comma-separated subset of "
                                     f"{', '.join(PhysicsOptions.SWITCHES)} (or default, "
                                     "all, none)")
            on[n] = True
    fields = {f.name for f in dataclasses.fields(PhysicsOptions)}
    for k, v in params.items():
        if v is None:
            continue
        if k not in fields or k in PhysicsOptions.SWITCHES:
            raise InputError(f"unknown physics parameter {k!r}")
        on[k] = v
    return check_physics(dataclasses.replace(base, **on))


def physics_json(opts: PhysicsOptions) -> str:
    """The options as a JSON string (recorded in ``frames.npz`` and ``summary.json``)."""
    return json.dumps(opts.to_dict(), sort_keys=True)


# ------------------------------------------------------------------------------------------------
# masses


def base_volumes(model) -> np.ndarray:
    """Printed volume of every base with its share of brackets and bumpers, both layers.

    Per base and layer: the base disc (radius ``base_r``, height ``layer_h``), per interior
    side a bumper prism ``base_th x base_th`` as long as half the flat gap to the partner
    (its flat length minus the two disc radii), and half of the cell's two V-brackets
    (section ``h x bracket_w``, two arms of length ``b / (2 cos alpha)`` each).  Alignment
    holes and marker pockets are ignored (< 3 %).

    Returns
    -------
    vol : (m,) float, mm^3
    """
    u = model.unit
    m = model.n_bases
    vol = np.full(m, 2 * math.pi * u.base_r**2 * u.layer_h)
    a, b = model.cell_bases[:, 0], model.cell_bases[:, 1]
    gap = np.linalg.norm(model.base_flat[b] - model.base_flat[a], axis=1) - 2 * u.base_r
    bumper = u.base_th**2 * np.maximum(gap, 0.0) / 2  # per base, per layer (half the gap)
    arm = model.cell_bracket_length / (2 * math.cos(u.alpha_rad))
    brackets = (2 * 2 * arm[:, None] * model.cell_thickness * u.bracket_w).sum(axis=1)  # cell
    per_cell = 2 * bumper + brackets / 2  # per side base: both layers' bumpers + half brackets
    vol += np.bincount(a, per_cell, minlength=m) + np.bincount(b, per_cell, minlength=m)
    return vol


def membrane_vertex_masses(model) -> np.ndarray:
    """Lumped latex volume (mm^3) of each membrane vertex: a third of each adjacent
    triangle's unstretched volume ``membrane_h * rest area`` (mass is conserved by the
    stretch)."""
    vol = model.consts.membrane_h * model.tri_rest_area
    return np.bincount(model.mem_triangles.ravel(), np.repeat(vol / 3, 3),
                       minlength=len(model.mem_point))


# ------------------------------------------------------------------------------------------------
# weight and plane


class ExternalTerms:
    """Weight (optionally buoyant) and a frictionless plane, on a :class:`ShellModel`.

    Energy ``sum_b W_b up.c_b + sum_v w_v up.x_v + k/3 sum_p max(0, z0 - up.x_p)^3`` with
    ``W_b`` the net weight of base b (printed volume; minus displaced water when ``wet``),
    ``w_v`` that of membrane vertex v, ``up`` the vertical (+z when the bottom layer faces
    down), and contact points ``x_p`` on the rim of both far faces of every base.  Bases are
    lumped at their centre (their centre of mass up to the bracket offsets).

    Parameters
    ----------
    model : ShellModel
    opts : PhysicsOptions
    wet : bool
        Subtract buoyancy (in water) or not (dry, on a table).
    weight : bool
        Include the weight (False: the plane only).
    plane : bool
        Include the plane (placed by :meth:`place_plane`).
    clamp : sequence of int, optional
        Bases held at their pose of :meth:`place_plane` (a support frame, a clamp), by
        springs of stiffness ``clamp_stiffness`` (N/mm) on four points of each (the centre
        and three points ``base_r`` away along the flat x, y, z axes).
    """

    def __init__(self, model, opts: PhysicsOptions, *, wet: bool, weight: bool = True,
                 plane: bool = True, clamp=(), clamp_stiffness: float = 1e6):
        self.model = model
        self.opts = opts
        self.up = np.array([0.0, 0.0, 1.0 if opts.face_down == "bottom" else -1.0])
        g = opts.gravity_mm_s2 * DENSITY_TO_T_MM3
        rw = opts.water_density if wet else 0.0
        self.base_volume = base_volumes(model)
        self.mem_volume = membrane_vertex_masses(model)
        on = 1.0 if weight else 0.0
        self.base_weight = on * (opts.print_density - rw) * g * self.base_volume  # (m,) N
        self.mem_weight = on * (opts.latex_density - rw) * g * self.mem_volume  # (v,) N
        u = model.unit
        n = opts.ground_points
        ang = 2 * np.pi * np.arange(n) / n
        ring = np.c_[u.base_r * np.cos(ang), u.base_r * np.sin(ang)]
        local = np.r_[np.c_[ring, np.full(n, u.layer_h)], np.c_[ring, np.full(n, -u.layer_h)]]
        self.local = local  # (2n, 3) flat-frame offsets from a base centre
        self.k = opts.ground_stiffness
        self.plane = plane
        self.z0 = -np.inf  # plane height along up; set by place_plane()
        self.clamp = np.asarray(clamp, dtype=np.int64).reshape(-1)
        self.clamp_k = float(clamp_stiffness)
        r = u.base_r
        self.clamp_local = np.array([[0, 0, 0], [r, 0, 0], [0, r, 0], [0, 0, r]], float)
        self.clamp_target = None

    def place_plane(self, state) -> float:
        """Put the plane under the lowest contact point of ``state``; returns its height."""
        P = self._points(state)[0]
        self.z0 = float((P @ self.up).min()) if self.plane else -np.inf
        if len(self.clamp):
            self.clamp_target = self._clamp_points(state)[0]
        return self.z0

    def _clamp_points(self, state):
        b = self.clamp
        v = np.einsum("mij,kj->mki", state.R[b], self.clamp_local)
        return state.c[b][:, None, :] + v, v

    def _points(self, state):
        v = np.einsum("mij,kj->mki", state.R, self.local)  # (m, 2n, 3) rotated offsets
        return (state.c[:, None, :] + v).reshape(-1, 3), v.reshape(-1, 3)

    def weight_total(self) -> float:
        """Net weight of the whole shell, N."""
        return float(self.base_weight.sum() + self.mem_weight.sum())

    def contact_forces(self, state) -> np.ndarray:
        """(m * 2n,) float, N: plane reaction at each contact point."""
        P, _ = self._points(state)
        pen = np.maximum(self.z0 - P @ self.up, 0.0)
        return self.k * pen * pen

    def evaluate(self, state, X, G, hessian: bool):
        """Energy and derivatives; adds the membrane weight to the point gradient ``G``.

        Parameters
        ----------
        state : State
        X : (p, 3) float, mm -- point positions of ``state``
        G : (p, 3) float or None -- point gradient to add the membrane weight to
        hessian : bool

        Returns
        -------
        E : float, N mm
        gb : (m, 6) float -- reduced gradient on every base (force N, torque N mm)
        Hb : (m, 6, 6) float or None -- reduced Hessian block of every base
        """
        m = len(state.c)
        up = self.up
        mp = self.model.mem_point
        E = float(self.base_weight @ (state.c @ up)) + float(self.mem_weight @ (X[mp] @ up))
        gb = np.zeros((m, 6))
        gb[:, :3] = self.base_weight[:, None] * up
        if G is not None:
            G[mp] += self.mem_weight[:, None] * up
        Hb = np.zeros((m, 6, 6)) if hessian else None
        if np.isfinite(self.z0):
            P, v = self._points(state)
            pen = np.maximum(self.z0 - P @ up, 0.0)
            hit = np.flatnonzero(pen > 0)
            if len(hit):
                E += self.k / 3 * float((pen[hit] ** 3).sum())
                body = hit // len(self.local)
                gp = -(self.k * pen[hit] ** 2)[:, None] * up  # (h, 3)
                gb[:, :3] += np.stack([np.bincount(body, gp[:, d], m) for d in range(3)], 1)
                tq = np.cross(v[hit], gp)
                gb[:, 3:] += np.stack([np.bincount(body, tq[:, d], m) for d in range(3)], 1)
                if hessian:
                    K = (2 * self.k * pen[hit])[:, None, None] * np.outer(up, up)
                    blk = jtkj(K, v[hit], v[hit])
                    gv = gp[:, :, None] * v[hit][:, None, :]
                    blk[:, 3:, 3:] += 0.5 * (gv + np.transpose(gv, (0, 2, 1))) - np.einsum(
                        "ni,ni->n", gp, v[hit])[:, None, None] * np.eye(3)
                    np.add.at(Hb, body, blk)
        if len(self.clamp):
            P, v = self._clamp_points(state)
            dx = P - self.clamp_target  # (c, 4, 3)
            E += 0.5 * self.clamp_k * float((dx * dx).sum())
            gp = self.clamp_k * dx
            gb[self.clamp, :3] += gp.sum(axis=1)
            gb[self.clamp, 3:] += np.cross(v, gp).sum(axis=1)
            if hessian:
                K = np.broadcast_to(self.clamp_k * np.eye(3), v.shape + (3,))
                blk = jtkj(np.ascontiguousarray(K), v, v)
                gv = gp[..., :, None] * v[..., None, :]
                blk[..., 3:, 3:] += 0.5 * (gv + np.swapaxes(gv, -1, -2)) - np.einsum(
                    "...i,...i->...", gp, v)[..., None, None] * np.eye(3)
                Hb[self.clamp] += blk.sum(axis=1)
        return E, gb, Hb

    def energy(self, state, X) -> float:
        """Energy only (N mm)."""
        return self.evaluate(state, X, None, False)[0]


__all__ = ["check_physics", "parse_physics", "physics_json", "base_volumes",
           "membrane_vertex_masses", "ExternalTerms", "DENSITY_TO_T_MM3"]


# ------------------------------------------------------------------------------------------------
# bracket bending out of plane


def bumper_stiffness(model, modulus) -> np.ndarray:
    """Contact stiffness of every bracket spring at its bumpers, N/mm (``bumper_compliance``).

    A layer's two bumpers of a cell meet end to end: two square prisms (side ``base_th``) in
    series, of total length ``L`` beyond the two base discs, which the layer's two bracket
    springs share.  At contact the spring's root-to-root length is ``L_c`` and the bases'
    centre distance ``L_c + 2 base_r cos alpha``, so ``L = L_c - 2 base_r (1 - cos alpha)``,
    floored at ``2 min_bumper`` (the design keeps every bumper at least that far out of
    its disc).  Each spring gets half the pair's ``E A / L``.  The discs add compliance that
    this leaves out, so the stiffness is an upper bound for the pair.

    Parameters
    ----------
    model : ShellModel -- ``spring_collision`` (4c,) mm and ``unit``
    modulus : float, MPa -- the polymer's (effective) modulus

    Returns
    -------
    (4c,) float, N/mm
    """
    u = model.unit
    stub = model.spring_collision - 2.0 * u.base_r * (1.0 - math.cos(u.alpha_rad))
    stub = np.maximum(stub, 2.0 * u.min_bumper)
    return float(modulus) * u.base_th ** 2 / (2.0 * stub)


def bending_stiffness(model, c1) -> np.ndarray:
    """Out-of-plane bending stiffness of every unit cell (N mm / rad) from the brackets'
    in-plane stiffness.

    Each bracket is taken as two arms of length ``a = b / (2 cos alpha)`` bending in plane as
    cantilevers, so its measured in-plane stiffness is ``c1 ~ 3 E I_in / a^3``.  The section
    is ``h`` (in plane) by ``w = bracket_w`` (out of plane): ``I_out = I_in (w / h)^2``.  Bent
    out of plane along its whole length ``2 a`` by an end rotation ``theta``, a bracket stores
    ``E I_out theta^2 / (2 * 2a)``, i.e. a rotational stiffness ``c1 a^2 (w/h)^2 / 6``.  The
    four brackets of a cell act in parallel.  An order-of-magnitude model: the beam formula
    and the V geometry are not checked against a measurement.

    Parameters
    ----------
    model : ShellModel
    c1 : (4c,) float, N/mm -- in-plane stiffness of every bracket spring (``coef[:, 0]``)

    Returns
    -------
    k : (c,) float, N mm / rad
    """
    u = model.unit
    a = model.spring_bracket_length / (2 * math.cos(u.alpha_rad))
    kb = np.asarray(c1, float) * a**2 * (u.bracket_w / model.spring_thickness) ** 2 / 6.0
    return kb.reshape(-1, 4).sum(axis=1)


class BracketBending:
    """Resistance of the brackets to bending out of the layer plane
    (``PhysicsOptions.bracket_bending``).

    Energy ``sum_cells k_c / 2 |n_a - n_b|^2`` with ``n = R e_z`` the normals of the cell's two
    bases (``|n_a - n_b| = 2 sin(theta / 2)`` for a relative tilt ``theta``): the brackets,
    glued to both bases, bend when the bases fold or twist against each other.  ``k`` is set
    per time step from the brackets' current stiffness (:func:`bending_stiffness`).
    """

    def __init__(self, model):
        self.model = model
        self.a, self.b = model.cell_bases[:, 0], model.cell_bases[:, 1]
        self.k = np.zeros(model.n_cells)
        self._pos = None

    def positions(self, pattern):
        """CSC positions of the rotation blocks (a,a), (b,b), (b,a) of every cell (lower)."""
        if self._pos is None:
            out = []
            for p, q in ((self.a, self.a), (self.b, self.b), (self.b, self.a),
                         (self.a, self.b)):
                rows = 6 * p[:, None, None] + 3 + np.arange(3)[None, :, None]
                cols = 6 * q[:, None, None] + 3 + np.arange(3)[None, None, :]
                rows, cols = np.broadcast_arrays(rows, cols)
                keep = rows >= cols
                out.append((keep, pattern.positions(rows[keep], cols[keep])))
            self._pos = out
        return self._pos

    def evaluate(self, state, hessian: bool, pattern=None):
        """Energy (N mm), reduced gradient on the bases (m, 6), and (with ``hessian``) a
        function adding the Hessian to CSC data of ``pattern``."""
        na, nb = state.R[self.a, :, 2], state.R[self.b, :, 2]
        d = na - nb
        k = self.k
        E = 0.5 * float(k @ np.einsum("ci,ci->c", d, d))
        ga = k[:, None] * d  # dE/dn_a; dE/dn_b = -ga
        m = len(state.c)
        gb = np.zeros((m, 6))
        ta, tb = np.cross(na, ga), np.cross(nb, -ga)
        for j in range(3):
            gb[:, 3 + j] = (np.bincount(self.a, ta[:, j], m) + np.bincount(self.b, tb[:, j], m))
        if not hessian:
            return E, gb, None
        I3 = np.eye(3)
        Sa, Sb = skew(na), skew(nb)
        kk = k[:, None, None]
        # dn/dtheta = -[n]x; J^T K J with K = k I, plus the second-order term of each base
        Haa = kk * (np.transpose(Sa, (0, 2, 1)) @ Sa)
        Hbb = kk * (np.transpose(Sb, (0, 2, 1)) @ Sb)
        Hba = -kk * (np.transpose(Sb, (0, 2, 1)) @ Sa)

        def second(g, n):
            gv = g[:, :, None] * n[:, None, :]
            return 0.5 * (gv + np.transpose(gv, (0, 2, 1))) - np.einsum(
                "ci,ci->c", g, n)[:, None, None] * I3

        Haa = Haa + second(ga, na)
        Hbb = Hbb + second(-ga, nb)

        def add(data):
            (ka, pa), (kb_, pb), (kba, pba), (kab, pab) = self.positions(pattern)
            np.add.at(data, pa, Haa[ka])
            np.add.at(data, pb, Hbb[kb_])
            np.add.at(data, pba, Hba[kba])
            np.add.at(data, pab, np.transpose(Hba, (0, 2, 1))[kab])

        return E, gb, add


__all__ += ["bending_stiffness", "BracketBending"]
