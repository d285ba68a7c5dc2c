"""Quasi-static morphing simulation: time stepping, bracket updates, frames, checkpoints.

Per time step (``shared/design/simulator.md`` §6.3, §7), with ``ps`` the bracket lengths of the
previous equilibrium:

1. ``t = 0`` is the **dry** step: brackets at their dry stiffness (material model at t = 0, no
   plasticity); the pre-stretched membrane contracts the flat shell slightly.
2. Every later step (``t = dt, 2 dt, ..., t_end``) is **wet**: force coefficients at time t
   with plastic scaling ``F(x / (1 - eta))``; rest length ``l = min(l, L0 - eta (L0 - ps))``;
   a spring whose ``ps <= L_c`` is in **bumper contact** for this step: rest ``L_c`` and
   ``E = kappa_c/2 (L - L_c)^2`` (two-sided, decided from the previous frame; with
   ``bumper_compliance`` the wet bumper pair's stiffness at t instead of ``kappa_c``).
3. Newton solve (:func:`pysolver.mechanics.solver.newton`, tolerance 1e-6 N), warm-started
   from the linear extrapolation of the last two frames (or the previous equilibrium when it
   still is one).
   A step that does not converge is kept (its best iterate), flagged ``converged = False``
   in the frames and the summary, and reported on stderr.
4. The mean of the base centres is reset to its flat value (global translation is free), and
   the net rotation of the solve is undone (global rotation is free: ``Simulation._unrotate``).
5. Early stop once every cell is at its bumpers in both layers and nothing moves any more.
   Divergence (NaN, energy above 100x the dry equilibrium, runaway motion) stops the run,
   keeps the frames so far and raises :class:`~pysolver.errors.MorphshellError` naming the
   step and the likely cause.

Output ``<design_dir>/sim/frames.npz`` (one frame per solve, ``t = 0, dt, ..., t_end``):

==========================  =====================  =============================================
key                         shape                  meaning
==========================  =====================  =============================================
``t``                       (n_frames,)            time in water, s (frame 0 = dry equilibrium)
``base_center``             (n_frames, m, 3)       base centre (flat face centroid), mm
``base_rotation``           (n_frames, m, 3, 3)    rotation flat pose -> current pose
``membrane_vertices``       (n_frames, v, 3)       membrane mesh vertices, mm
``membrane_triangles``      (t, 3)                 membrane triangles (vertex ids)
``bracket_length``          (n_frames, c, 4)       spring lengths (index 2 layer + q), mm
``collided``                (n_frames, c, 4)       spring at its bumper: contact switch on
                                                   during the solve, or L <= L_c after it
``contact``                 (n_frames, c, 4)       contact switch active during the solve
``newton_iterations``       (n_frames,)            Newton iterations of the solve
``newton_regularised``      (n_frames,)            iterations needing more than the base shift
                                                   (indefinite Hessian: buckling, snapping)
``residual``                (n_frames,)            final residual, N (see pysolver.mechanics.solver)
``wall_s``                  (n_frames,)            wall time of the solve, s
``converged``               (n_frames,)            residual below tolerance
``energy``                  (n_frames,)            total energy, N mm
``marker_top/_bottom``      (n_frames, m, 3)       marker-dot tip = far-face centre per layer, mm
``collision_length``        (c, 4)                 bumper contact length L_c per spring, mm
``flat_base_center``        (m, 3)                 flat base centres, mm
``flat_membrane_vertices``  (v, 3)                 flat membrane vertices, mm
``membrane_base``           (v,)                   base a vertex is attached to (-1 = free)
``tables_sha256``           ()                     :func:`pysolver.tables.tables_sha256` of the
                                                   tables simulated (the report checks it)
==========================  =====================  =============================================

Any base point ``p`` given in the flat shell frame is at ``c + R (p - c_flat)`` in a frame.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from pysolver.core.progress import Steps, say
from pysolver.core.records import json_text
from pysolver.core.writes import atomic_file, atomic_write_text, remove_file
from pysolver.errors import InputError, MorphshellError
from pysolver.geometry import rigid_fit
from pysolver.material.bumper import bumper_modulus, dry_bumper_modulus
from pysolver.material.model import load_bracket_model
from pysolver.material.relaxation import relaxation_factor
from pysolver.mechanics.energies import ShellEnergy, State
from pysolver.mechanics.model import ShellModel, load_model
from pysolver.mechanics.solver import SOLVERS, LinearSolver, StaticProblem, newton
from pysolver.params import NEWTON, PHYSICS_DEFAULT, SIM, UNIT_CELL, PhysicsOptions
from pysolver.params import tol as TOL
from pysolver.tables import tables_sha256

from .collisions import completion_times
from .contact import BaseContact
from .physics import (
    BracketBending,
    ExternalTerms,
    bending_stiffness,
    bumper_stiffness,
    check_physics,
    physics_json,
)

FRAMES_NAME = "frames.npz"
CHECKPOINT_NAME = "checkpoint.npz"
CHECKPOINT_VERSION = 1


@dataclass(frozen=True)
class SimSettings:
    """Time stepping and solver settings.

    Attributes
    ----------
    t_end, dt : float, s
    eta : float -- plastic fraction (wet steps)
    tol : float, N -- Newton residual tolerance
    max_iter_dry, max_iter_wet : int
    settle_mm : float, mm
        Early stop: every cell in bumper contact in both layers (one spring per layer, as in
        :func:`completion_times`) and no base centre or vertex moved more than this in a step.
    blowup : float
        Divergence: total energy above ``blowup`` times the dry equilibrium energy.
    checkpoint_every : int
        Save a checkpoint every this many steps (0 = never).
    predictor : bool or "guarded"
        Warm start each solve from the extrapolation of the last frames (see
        ``Simulation._predict``); ``False``: from the previous equilibrium.
    solver : {"fast", "reference"}
        Linear-algebra threading of the Newton solves (:data:`~pysolver.mechanics.solver.SOLVERS`):
        ``fast``
        runs every solve on one BLAS thread, ``reference`` as before it was measured.  Same
        results; the reference path is kept for ``make bench``'s comparison.
    physics : PhysicsOptions
        Effects beyond the reference simulator (``docs/physics.md``); default
        :data:`~pysolver.params.PHYSICS_DEFAULT`, the reference model is
        :data:`~pysolver.params.PHYSICS_OFF`.
    """

    t_end: float = SIM.t_end
    dt: float = SIM.dt
    eta: float = SIM.eta
    tol: float = TOL.newton_grad
    max_iter_dry: int = NEWTON.max_iter_dry
    max_iter_wet: int = NEWTON.max_iter_wet
    settle_mm: float = SIM.settle_mm
    blowup: float = SIM.blowup
    checkpoint_every: int = SIM.checkpoint_every
    predictor: bool | str = True
    solver: str = "fast"
    physics: PhysicsOptions = PHYSICS_DEFAULT

    def __post_init__(self):

        check_physics(self.physics)
        if self.solver not in SOLVERS:
            raise InputError(f"solver {self.solver!r} is not one of {', '.join(SOLVERS)}",
                             fix="use --solver fast (the default) or --solver reference")

    def times(self) -> np.ndarray:
        n = int(round(self.t_end / self.dt))
        if n < 0 or abs(n * self.dt - self.t_end) > TOL.rel * max(1.0, self.t_end):
            raise InputError(f"t_end = {self.t_end} s is not a non-negative multiple of "
                             f"dt = {self.dt} s", fix="choose t_end = k * dt")
        return self.dt * np.arange(n + 1)


class Simulation:
    """Time stepper over a :class:`~pysolver.mechanics.ShellModel` (in memory).

    Parameters
    ----------
    model : ShellModel
    material : object
        Bracket model with ``coefficients(h_mm, b_mm, t_s, eta=0.0) -> (n, 4)``
        (:class:`pysolver.material.model.BracketModel`).
    settings : SimSettings
    """

    def __init__(self, model: ShellModel, material, settings: SimSettings = SimSettings()):
        if not hasattr(material, "coefficients"):
            raise InputError(f"material {material!r} has no coefficients(h, b, t, eta) method",
                             fix="pass a pysolver.material BracketModel")
        check_model_physics(model, settings.physics)
        self.model = model
        self.material = material
        self.settings = settings
        self.times = settings.times()
        self.energy = ShellEnergy(model)
        self.state = State.flat(model)
        self.linear = LinearSolver(solver=settings.solver)
        self.rest = model.spring_rest0.copy()
        self.contact = np.zeros(len(self.rest), dtype=bool)
        self.prev_lengths = None
        self.k = 0  # next frame index
        self.E_ref = None
        nf, m, c = len(self.times), model.n_bases, model.n_cells
        nv = len(model.mem_point)
        self.frames = {
            "t": np.full(nf, np.nan),
            "base_center": np.zeros((nf, m, 3)),
            "base_rotation": np.zeros((nf, m, 3, 3)),
            "membrane_vertices": np.zeros((nf, nv, 3)),
            "bracket_length": np.zeros((nf, c, 4)),
            "collided": np.zeros((nf, c, 4), dtype=bool),
            "contact": np.zeros((nf, c, 4), dtype=bool),
            "newton_iterations": np.zeros(nf, dtype=np.int64),
            "newton_regularised": np.zeros(nf, dtype=np.int64),
            "residual": np.zeros(nf),
            "wall_s": np.zeros(nf),
            "converged": np.zeros(nf, dtype=bool),
            "energy": np.zeros(nf),
            "marker_top": np.zeros((nf, m, 3)),
            "marker_bottom": np.zeros((nf, m, 3)),
        }
        self.stopped_early = False
        self._free_hist = []  # free vertices of the last two frames, oldest first
        self.rest_frame = None  # dry resting shape on a table (physics.dry_rest)
        ph = settings.physics
        if ph.gravity:

            self.energy.external = ExternalTerms(model, ph, wet=True)
            self.energy.external.place_plane(self.state)
        if ph.contact:

            self.energy.contact = BaseContact(model, ph)
        if ph.bracket_bending:

            self.energy.bending = BracketBending(model)

    # -- helpers -------------------------------------------------------------------------------
    def contact_stiffness(self, t: float) -> np.ndarray:
        """Stiffness of each bracket spring at its bumpers at ``t`` s in water, N/mm: the
        reference's penalty ``kappa_c``, or with ``bumper_compliance`` the wet bumper pair's
        (:func:`sim.model.physics.bumper_stiffness` of the polymer's modulus at ``t``)."""
        md = self.model
        if self.settings.physics.bumper_compliance:
            return bumper_stiffness(md, float(bumper_modulus(t)))
        return np.full(len(md.spring_collision), md.consts.kappa_c)

    def spring_lengths(self, state: State | None = None) -> np.ndarray:
        X, _ = self.energy.positions(self.state if state is None else state)
        sp_ = self.model.spring_points
        return np.linalg.norm(X[sp_[:, 1]] - X[sp_[:, 0]], axis=1)

    def update_brackets(self, t: float, dry: bool) -> None:
        """Set rest lengths, force coefficients and contact switches for the solve at t."""
        md = self.model
        eta = 0.0 if dry else self.settings.eta
        coef = np.asarray(self.material.coefficients(md.spring_thickness,
                                                     md.spring_bracket_length, t, eta=eta),
                          float).reshape(-1, 4)
        coef0 = coef[:, 0].copy()  # the brackets' own stiffness (before bumper contact)
        if not dry and self.prev_lengths is not None:
            ps = self.prev_lengths
            L0 = md.spring_rest0
            self.rest = np.minimum(self.rest, L0 - eta * (L0 - ps))
            self.contact = ps <= md.spring_collision
            self.rest[self.contact] = md.spring_collision[self.contact]
            coef[self.contact] = 0.0
            coef[self.contact, 0] = self.contact_stiffness(t)[self.contact]
        self.energy.spring_rest = self.rest
        self.energy.spring_coef = coef
        ph = self.settings.physics
        if ph.bracket_bending:

            self.energy.bending.k = bending_stiffness(md, coef0)
        if ph.relaxation or ph.membrane_temperature:
            self.energy.mu_scale = membrane_scale(ph, t, wet=True)

    def _record(self, t, res, L) -> None:
        md, s, k, fr = self.model, self.state, self.k, self.frames
        X, _ = self.energy.positions(s)
        c = md.n_cells
        fr["t"][k] = t
        fr["base_center"][k] = s.c
        fr["base_rotation"][k] = s.R
        fr["membrane_vertices"][k] = X[md.mem_point]
        fr["bracket_length"][k] = L.reshape(c, 4)
        fr["contact"][k] = self.contact.reshape(c, 4)
        fr["collided"][k] = (self.contact | (L <= md.spring_collision)).reshape(c, 4)
        fr["newton_iterations"][k] = res.iterations
        fr["newton_regularised"][k] = res.regularised
        fr["residual"][k] = res.residual
        fr["wall_s"][k] = res.wall_s
        fr["converged"][k] = res.converged
        fr["energy"][k] = res.energy
        h = md.unit.layer_h
        fr["marker_top"][k] = s.c + s.R[:, :, 2] * h
        fr["marker_bottom"][k] = s.c - s.R[:, :, 2] * h

    def _unrotate(self, before: State) -> None:
        """Undo the net rotation of the step's solve (the rotation gauge).

        Nothing holds the shell, and its energy does not change when the whole shell turns:
        the Newton steps are only regularised along that null space
        (``pysolver.mechanics.solver``), so the round-off of each solve turns the whole shell a
        little, differently on each BLAS and thread count, and the predictor extrapolates the
        turn (the benchmark shell spun by 144 degrees over its run; the two solver paths
        differed by 0.009 mm, and by 7e-10 mm after a rigid fit).  The best-fit rotation (Kabsch,
        :func:`pysolver.geometry.rigid_fit`, turned about the centroid) of this step's base
        centres and free vertices onto the previous frame's is undone, so a frame has no net
        rotation relative to the previous one and the result no longer depends on that
        round-off.  With weight and a table
        (``physics.gravity``) only the turn about the vertical is free, and only it is undone.
        """
        s = self.state
        P = np.concatenate([s.c, s.f])
        Q = np.concatenate([before.c, before.f])
        pc, qc = P.mean(axis=0), Q.mean(axis=0)
        if self.energy.external is None:
            lam = np.linalg.eigvalsh((P - pc).T @ (P - pc))  # ascending, mm^2
            if lam[1] <= TOL.degenerate * lam[2]:  # collinear: the turn about the line is
                return                             # undefined
            Rg, _ = rigid_fit(P, Q)  # Rg (p - pc) ~ q - qc
        else:
            up = np.abs(self.energy.external.up)
            e1, e2 = np.eye(3)[np.argsort(up)[:2]]  # the horizontal axes
            A, B = P - pc, Q - qc
            a = float(np.sum((A @ e1) * (B @ e2) - (A @ e2) * (B @ e1)))
            b = float(np.sum((A @ e1) * (B @ e1) + (A @ e2) * (B @ e2)))
            th = np.arctan2(a, b)
            w = np.cross(e1, e2)  # the turn by th about w maps e1 towards e2
            K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
            Rg = np.eye(3) + np.sin(th) * K + (1.0 - np.cos(th)) * (K @ K)
        s.c = (s.c - pc) @ Rg.T + pc
        s.f = (s.f - pc) @ Rg.T + pc
        s.R = Rg @ s.R

    def _recentre(self) -> None:
        shift = self.state.c.mean(axis=0) - self.model.base_flat.mean(axis=0)
        if self.energy.external is not None:
            shift = shift * (1.0 - np.abs(self.energy.external.up))  # the plane fixes height
        self.state.c = self.state.c - shift
        self.state.f = self.state.f - shift

    # -- stepping ------------------------------------------------------------------------------
    @property
    def done(self) -> bool:
        return self.k >= len(self.times) or self.stopped_early

    def step(self):
        """Solve the next time step and record its frame.

        Returns
        -------
        NewtonResult

        Raises
        ------
        MorphshellError
            The simulation diverged (NaN, energy blow-up, runaway motion).
        """
        t = float(self.times[self.k])
        dry = self.k == 0
        st = self.settings
        self.update_brackets(t, dry)
        before = self.state.copy()
        start = self.state
        if st.predictor and self.energy.residual(self.energy.gradient(self.state)[1]) >= st.tol:
            start = self._predict()  # (the previous equilibrium is kept when still one)
        problem = StaticProblem(self.energy, start)
        res = newton(problem, tol=st.tol, linear=self.linear,
                     max_iter=st.max_iter_dry if dry else st.max_iter_wet)
        if res.status == "nan" and res.iterations == 0 and start is not self.state:
            # the extrapolation left the energy's domain: start from the last equilibrium
            problem = StaticProblem(self.energy, self.state)
            res = newton(problem, tol=st.tol, linear=self.linear,
                         max_iter=st.max_iter_dry if dry else st.max_iter_wet)
        self.state = problem.state
        self.state.orthonormalize()
        cause = self._divergence(res, t)
        if cause is not None:
            self.state = before
            raise MorphshellError(f"simulation diverged at step {self.k} (t = {t:g} s): "
                                  f"{cause}", fix=self._divergence_fix(cause))
        self._unrotate(before)
        self._recentre()
        L = self.spring_lengths()
        self._record(t, res, L)
        if self.E_ref is None:
            self.E_ref = max(abs(res.energy), TOL.energy_floor)
        # early stop: every cell at its bumpers in both layers and nothing moved
        ct = self.contact.reshape(-1, 4)
        if not dry and np.all((ct[:, 0] | ct[:, 1]) & (ct[:, 2] | ct[:, 3])):
            moved = max(np.abs(self.state.c - before.c).max(initial=0.0),
                        np.abs(self.state.f - before.f).max(initial=0.0))
            if moved < st.settle_mm:
                self.stopped_early = True
        self.prev_lengths = L
        self._free_hist = [*self._free_hist[-1:], self.state.f.copy()]
        self.k += 1
        return res

    def _predict(self) -> State:
        """Warm start: the linear extrapolation of the last two frames.

        Centres and free vertices are extrapolated componentwise, rotations through their
        frame-to-frame increment.  With ``predictor="guarded"`` the previous equilibrium is
        kept when the extrapolation has a higher energy; by default the extrapolation is used
        whenever its energy is finite: on the benchmark it is 5-10x closer to the new
        equilibrium than the previous one even when its energy is higher (the shell moves
        along soft modes, the extrapolation misfits stiff ones a little), which saves ~30 % of
        the Newton iterations (quadratic extrapolation from three frames was worse).
        """
        k, fr, hist = self.k, self.frames, self._free_hist
        if k < 2 or len(hist) < 2:
            return self.state
        c0, c1 = fr["base_center"][k - 2], fr["base_center"][k - 1]
        R0, R1 = fr["base_rotation"][k - 2], fr["base_rotation"][k - 1]
        pred = State(2 * c1 - c0, (R1 @ np.transpose(R0, (0, 2, 1))) @ R1,
                     2 * hist[-1] - hist[-2])
        pred.orthonormalize()
        if self.settings.predictor != "guarded":
            return pred  # (a non-finite energy there is caught by step(): solved from the last)
        E_pred = self.energy.energy(pred)
        if E_pred >= self.energy.energy(self.state):
            return self.state
        return pred if np.isfinite(E_pred) else self.state

    def _divergence(self, res, t):
        s = self.state
        if res.status == "nan" or not np.isfinite(res.energy) or not (
                np.all(np.isfinite(s.c)) and np.all(np.isfinite(s.f))):
            return "NaN in the energy or the positions" + self._likely_cause()
        if self.E_ref is not None and res.energy > self.settings.blowup * self.E_ref:
            return (f"energy blow-up ({res.energy:.4g} N mm > {self.settings.blowup:g} x the dry "
                    f"equilibrium {self.E_ref:.4g} N mm)" + self._likely_cause())
        size = np.ptp(self.model.base_flat, axis=0).max() + 10.0
        drift = np.abs(s.c - self.model.base_flat).max(initial=0.0)
        if drift > 10 * size:
            return f"runaway motion (a base moved {drift:.3g} mm)" + self._likely_cause()
        return None

    def _likely_cause(self) -> str:
        md = self.model
        X, _ = self.energy.positions(self.state)
        if not np.all(np.isfinite(X)):
            return "; likely cause: the Newton step left the physical range (try a smaller dt)"
        L = np.linalg.norm(X[md.spring_points[:, 1]] - X[md.spring_points[:, 0]], axis=1)
        x = self.rest - L
        over = np.flatnonzero((x > md.spring_bracket_length) & ~self.contact)
        if len(over):
            i = int(over[np.argmax(x[over])])
            return (f"; likely cause: bracket spring {i} of cell {i // 4} is compressed by "
                    f"{x[i]:.3g} mm, beyond its flat length b = "
                    f"{md.spring_bracket_length[i]:.3g} mm (outside the fitted range; "
                    "bumper missed?)")
        P = X[md.tri_points]
        e1, e2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
        a = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
        ratio = a / (md.tri_rest_area * md.consts.tau**2)
        j = int(np.argmin(ratio))
        if ratio[j] < TOL.membrane_collapse:
            b = md.mem_body[md.mem_triangles[j]]
            return (f"; likely cause: membrane triangle {j} collapsed (area ratio "
                    f"{ratio[j]:.2g}) next to base(s) {sorted(set(b[b >= 0].tolist()))}")
        return "; likely cause: unknown (check the solver residual history in frames.npz)"

    @staticmethod
    def _divergence_fix(cause: str) -> str:
        if "bracket spring" in cause:
            return ("check the cell's collision lengths and thickness in cells.csv; re-run the "
                    "design and program stages")
        return "re-run with a smaller dt (e.g. --dt 0.25) and inspect the last frames"

    # -- output --------------------------------------------------------------------------------
    def frames_dict(self) -> dict:
        """Frames so far plus the static arrays (see module docstring)."""
        md, n = self.model, self.k
        out = {k: v[:n].copy() for k, v in self.frames.items()}
        out.update({
            "membrane_triangles": md.mem_triangles.copy(),
            "collision_length": md.spring_collision.reshape(-1, 4).copy(),
            "flat_base_center": md.base_flat.copy(),
            "flat_membrane_vertices": md.mem_flat.copy(),
            "membrane_base": md.mem_body.copy(),
            "stopped_early": np.array(self.stopped_early),
            "physics": np.array(physics_json(self.settings.physics)),
        })
        if self.rest_frame is not None:
            out.update(self.rest_frame)
        return out

    # -- dry resting shape (physics.dry_rest) ----------------------------------------------------
    def dry_rest(self):
        """The dry shell resting on a table after the morph; fills :attr:`rest_frame`.

        The brackets cool and stiffen under the load they carry: a shape-memory polymer
        cooled under load keeps its shape and its stress, so every bracket spring keeps the
        force it had at the end of the morph, and any further deformation meets the dry
        stiffness (material model at t = 0, no plasticity).  That is a dry spring whose rest
        length sits ``x0`` beyond the final length, ``F_dry(x0) = F_end``
        (:func:`frozen_rest_lengths`).  Springs at their bumpers stay in contact.  The
        membrane is back at room temperature (``membrane_temperature``) and has relaxed
        for ``drying_min`` more (``relaxation``).  The shell gets its full (dry) weight and
        a frictionless table under its lowest point; the static equilibrium is solved.

        Returns
        -------
        NewtonResult
        """
        md, k = self.model, self.model.consts
        ph = self.settings.physics
        L = self.spring_lengths()
        f_end = spring_forces(self.energy.spring_coef, self.energy.spring_rest - L)
        coef = np.asarray(self.material.coefficients(md.spring_thickness,
                                                     md.spring_bracket_length, 0.0, eta=0.0),
                          float).reshape(-1, 4)
        if self.energy.bending is not None:

            self.energy.bending.k = bending_stiffness(md, coef[:, 0])
        rest = L + frozen_rest_lengths(coef, f_end, md.spring_bracket_length)
        c = self.contact
        if ph.bumper_compliance:  # the bumpers cooled under their load, as the brackets
            kd = bumper_stiffness(md, dry_bumper_modulus())
            rest[c] = L[c] + f_end[c] / kd[c]
        else:
            kd = np.full(len(L), k.kappa_c)
            rest[c] = md.spring_collision[c]
        coef[c] = 0.0
        coef[c, 0] = kd[c]
        self.energy.spring_rest, self.energy.spring_coef = rest, coef
        if ph.relaxation or ph.membrane_temperature:
            t_out = float(self.frames["t"][self.k - 1]) if self.k else 0.0
            self.energy.mu_scale = membrane_scale(ph, t_out + 60.0 * ph.drying_min, wet=False)
        ext = ExternalTerms(md, self.settings.physics, wet=False)
        ext.place_plane(self.state)
        self.energy.external = ext
        problem = StaticProblem(self.energy, self.state.copy())
        res = newton(problem, tol=self.settings.tol, linear=self.linear,
                     max_iter=NEWTON.max_iter_rest)
        s = problem.state
        s.orthonormalize()
        X, _ = self.energy.positions(s)
        h = md.unit.layer_h
        self.rest_frame = {
            "rest_base_center": s.c.copy(), "rest_base_rotation": s.R.copy(),
            "rest_membrane_vertices": X[md.mem_point].copy(),
            "rest_marker_top": s.c + s.R[:, :, 2] * h, "rest_marker_bottom": s.c - s.R[:, :, 2] * h,
            "rest_converged": np.array(res.converged), "rest_residual": np.array(res.residual),
            "rest_plane_height": np.array(ext.z0), "rest_weight_N": np.array(ext.weight_total()),
            "rest_contact_force_N": np.array(float(ext.contact_forces(s).sum())),
        }
        return res

    # -- checkpoints ----------------------------------------------------------------------------
    def checkpoint_arrays(self, fingerprint: str) -> dict:
        d = {"_" + k: v[: self.k] for k, v in self.frames.items()}
        d.update({"version": np.array(CHECKPOINT_VERSION), "fingerprint": np.array(fingerprint),
                  "k": np.array(self.k), "c": self.state.c, "R": self.state.R,
                  "f": self.state.f, "rest": self.rest, "contact": self.contact,
                  "prev_lengths": (self.prev_lengths if self.prev_lengths is not None
                                   else np.zeros(0)),
                  "E_ref": np.array(np.nan if self.E_ref is None else self.E_ref),
                  "shift_hint": np.array(self.linear.shift_hint),
                  "free_hist": (np.stack(self._free_hist) if self._free_hist
                                else np.zeros((0,) + self.state.f.shape)),
                  "stopped_early": np.array(self.stopped_early)})
        return d

    def restore(self, z) -> None:
        k = int(z["k"])
        for key, arr in self.frames.items():
            arr[:k] = z["_" + key]
        self.k = k
        self.state = State(np.array(z["c"]), np.array(z["R"]), np.array(z["f"]))
        self.rest = np.array(z["rest"])
        self.contact = np.array(z["contact"], dtype=bool)
        pl = np.array(z["prev_lengths"])
        self.prev_lengths = pl if pl.size else None
        E = float(z["E_ref"])
        self.E_ref = None if np.isnan(E) else E
        self.stopped_early = bool(z["stopped_early"])
        self.linear.shift_hint = float(z["shift_hint"])
        self._free_hist = list(np.array(z["free_hist"]))


# ------------------------------------------------------------------------------------------------
# membrane and bracket state helpers


MODEL_EFFECTS = ("rim", "rim_margin_mm", "rim_stretch", "clearance")
"""Physics options that shape the model itself (:func:`pysolver.mechanics.build_model`)."""


def check_model_physics(model: ShellModel, physics: PhysicsOptions) -> None:
    """Refuse a model built with other model-level physics than the simulation's.

    ``rim`` and ``clearance`` change the model (its membrane mesh, its contact lengths), so a
    model built with one set of options cannot be simulated with another.
    """
    mp = getattr(model, "physics", None)
    if mp is None:
        return
    if mp.rim != physics.rim or mp.clearance != physics.clearance or (
            physics.rim and (mp.rim_margin_mm, mp.rim_stretch)
            != (physics.rim_margin_mm, physics.rim_stretch)):
        diff = [k for k in MODEL_EFFECTS if getattr(mp, k) != getattr(physics, k)]
        raise InputError(f"the shell model was built with other physics than the simulation's "
                         f"({', '.join(diff)})",
                         fix="build the model with the simulation's options: "
                             "load_model(folder, physics=settings.physics)")


def membrane_scale(physics: PhysicsOptions, t: float, wet: bool) -> float:
    """Factor on the membrane modulus ``mu`` at time ``t`` (s) after immersion.

    The measured stress relaxation at the membrane's age (``relaxation``: stretched
    ``stretch_to_glue_min + glue_to_water_min`` before immersion) times the entropic
    temperature factor in the water (``membrane_temperature``,
    :meth:`pysolver.params.PhysicsOptions.temperature_factor`).
    """
    g = 1.0
    if physics.relaxation:
        age = 60.0 * (physics.stretch_to_glue_min + physics.glue_to_water_min) + t
        g = float(relaxation_factor(age))
    return g * physics.temperature_factor(wet=wet)


def spring_forces(coef, x) -> np.ndarray:
    """Force of every bracket spring, N (compression positive), ``F(x) = c1 x + .. + c4 x^4``.

    Parameters
    ----------
    coef : (n, 4) float -- force coefficients (the energy's ``spring_coef``)
    x : (n,) float, mm -- compression ``rest - length``
    """
    c = np.asarray(coef, float)
    x = np.asarray(x, float)
    return x * (c[:, 0] + x * (c[:, 1] + x * (c[:, 2] + x * c[:, 3])))


def frozen_rest_lengths(coef, force, limit, iters: int = 40) -> np.ndarray:
    """Compression ``x0`` (mm) at which springs with force coefficients ``coef`` carry
    ``force`` (N): the dry spring that keeps a cooled bracket's load.

    Solved by safeguarded Newton on ``[-limit, limit]`` per spring (the force laws are
    monotone there: ``F' >= 0`` on the fitted range, and the dry stiffness is large, so
    ``x0`` stays small); a spring that carries no force gets ``x0 = 0``.

    Parameters
    ----------
    coef : (n, 4) float -- dry force coefficients
    force : (n,) float, N
    limit : (n,) float, mm -- bracket length b (bound of the search)

    Returns
    -------
    (n,) float, mm
    """
    c = np.asarray(coef, float)
    f = np.asarray(force, float)
    b = np.asarray(limit, float)
    k0 = np.maximum(c[:, 0], TOL.tiny)
    x = np.clip(f / k0, -b, b)
    lo, hi = -b.copy(), b.copy()
    for _ in range(iters):
        r = spring_forces(c, x) - f
        lo = np.where(r < 0, x, lo)
        hi = np.where(r > 0, x, hi)
        d = c[:, 0] + x * (2 * c[:, 1] + x * (3 * c[:, 2] + x * 4 * c[:, 3]))
        xn = x - r / np.where(d > 0, d, np.inf)
        bad = ~((xn > lo) & (xn < hi))
        x = np.where(bad, 0.5 * (lo + hi), xn)
    return np.where(f == 0.0, 0.0, x)


# ------------------------------------------------------------------------------------------------
# files


def _atomic_savez(path: Path, arrays: dict) -> None:
    """``np.savez`` through a temporary file in the same folder and an atomic rename."""
    with atomic_file(path) as tmp:
        np.savez(tmp, **arrays)


def _material_id(material) -> str:
    """A fingerprint of the bracket model (class, file, and coefficients at probe points)."""
    h = np.linspace(UNIT_CELL.thickness_min, UNIT_CELL.thickness_max, 3)
    probe = np.asarray(material.coefficients(h, np.array([1.0, 2.5, 5.0]),
                                             np.array([0.0, 30.0, 90.0])), float)
    return f"{type(material).__name__}|{getattr(material, 'path', '')}|{probe.tobytes().hex()}"


def _resolve_material(material):
    if material is None or isinstance(material, str | os.PathLike):

        return load_bracket_model(material)
    return material


def run_simulation(sim: Simulation, *, progress: bool = True, label: str = "sim",
                   checkpoint: Path | None = None, fingerprint: str = "",
                   frames_path: Path | None = None) -> dict:
    """Run ``sim`` to the end (or early stop), with progress lines and checkpoints.

    Progress: one line per step, ``[simulate] <label>: k/n t=... newton ... ETA s``
    (:class:`pysolver.core.progress.Steps`).  On divergence the frames so far are written to
    ``frames_path`` (if given) and the :class:`MorphshellError` is re-raised.
    """
    st = sim.settings
    t_start = time.perf_counter()
    last_ckpt = sim.k
    steps = Steps("simulate", label, len(sim.times) - 1, enabled=progress)
    while not sim.done:
        t0 = time.perf_counter()
        try:
            res = sim.step()
        except MorphshellError:
            if frames_path is not None and sim.k > 0:
                _atomic_savez(frames_path, sim.frames_dict())
            raise
        w = time.perf_counter() - t0
        k = sim.k - 1
        flag = "" if res.converged else f"  NOT CONVERGED ({res.status})"
        steps.step(f"t={sim.times[k]:6.1f} s  newton {res.iterations:3d}  "
                   f"|g| {res.residual:.1e} N  {w:5.2f} s{flag}", k=k)
        if checkpoint is not None and st.checkpoint_every and (
                sim.k - last_ckpt >= st.checkpoint_every) and not sim.done:
            _atomic_savez(checkpoint, sim.checkpoint_arrays(fingerprint))
            last_ckpt = sim.k
    extra = {}
    if st.physics.any:
        extra["physics"] = st.physics.to_dict()
    if st.physics.dry_rest and sim.rest_frame is None:
        t0 = time.perf_counter()
        res = sim.dry_rest()
        extra["dry_rest"] = {"converged": bool(res.converged), "residual_N": res.residual,
                             "newton_iterations": res.iterations,
                             "wall_s": round(time.perf_counter() - t0, 3)}
        say("simulate", label, f"dry rest on a table: newton {res.iterations} |g| "
            f"{res.residual:.1e} N{'' if res.converged else '  NOT CONVERGED'}", progress)
    fr = sim.frames
    nf = sim.k
    return {**extra, "steps": nf, "wall_s": round(time.perf_counter() - t_start, 3),
            "converged_steps": int(fr["converged"][:nf].sum()),
            "nonconverged_steps": [int(i) for i in np.flatnonzero(~fr["converged"][:nf])],
            "newton_iterations_total": int(fr["newton_iterations"][:nf].sum()),
            "linear_solver": dict(sim.linear.timings(), solver=st.solver),
            "newton_iterations_max": int(fr["newton_iterations"][:nf].max(initial=0)),
            "residual_max_N": float(fr["residual"][:nf].max(initial=0.0)),
            "final_energy_Nmm": float(fr["energy"][nf - 1]) if nf else float("nan"),
            "t_final_s": float(fr["t"][nf - 1]) if nf else float("nan"),
            "stopped_early": bool(sim.stopped_early)}


def simulate_model(model: ShellModel, material, *, t_end: float = SIM.t_end,
                   dt: float = SIM.dt, progress: bool = False, **settings) -> dict:
    """Simulate a model in memory and return its frames (no files).

    ``settings`` are :class:`SimSettings` fields; without ``physics`` the model is simulated
    with the physics it was built with (``model.physics``: :func:`~pysolver.mechanics.load_model`
    builds with the default, :func:`~pysolver.mechanics.build_model` with none).

    Returns
    -------
    frames : dict
        As in ``frames.npz``, plus ``"summary"`` (dict).
    """
    settings.setdefault("physics", getattr(model, "physics", PHYSICS_DEFAULT))
    sim = Simulation(model, material, SimSettings(t_end=t_end, dt=dt, **settings))
    summary = run_simulation(sim, progress=progress)
    out = sim.frames_dict()
    out["summary"] = summary
    return out


def simulate_design(design_dir, *, t_end: float = SIM.t_end, dt: float = SIM.dt, material=None,
                    progress: bool = True, resume: bool = True,
                    checkpoint_every: int = SIM.checkpoint_every,
                    **settings) -> dict:
    """Simulate the morph of a design folder; write ``<design_dir>/sim/frames.npz``.

    Parameters
    ----------
    design_dir : path-like
        Design folder (``bases.csv``, ``cells.csv`` with thicknesses, ``stencil.obj``).
    t_end, dt : float, s
        Simulated time in water and time step (frames at ``0, dt, ..., t_end``).
    material : BracketModel or path-like, optional
        Bracket model (default: the committed fitted model).
    progress : bool
        One line per step on stderr.
    resume : bool
        Continue from ``sim/checkpoint.npz`` when it matches the design, material and settings.
    checkpoint_every : int
        Steps between checkpoints (0 = no checkpoints).

    Returns
    -------
    summary : dict
        ``steps``, ``converged_steps``, ``nonconverged_steps``, ``wall_s``, ``final_energy_Nmm``,
        ``t_final_s``, ``stopped_early``, ``completed_cells``, model sizes, ``frames`` path.

    Raises
    ------
    InputError
        Bad design folder or settings.
    MorphshellError
        The simulation diverged (frames so far are kept in ``frames.npz``).

    Examples
    --------
    The first 10 s in water of the ``folder`` programmed in
    :func:`pysolver.temporal.program_design`'s example:

    >>> from sim.model.simulate import simulate_design
    >>> r = simulate_design(folder, t_end=10.0, progress=False)
    >>> r["t_final_s"] <= 10.0, (folder / "sim" / "frames.npz").is_file()
    (True, True)
    """
    folder = Path(design_dir)
    mat = _resolve_material(material)  # a bad model file is refused before anything else
    made_from = tables_sha256(folder)   # the tables these frames are simulated from
    model = load_model(folder, physics=settings.get("physics", PHYSICS_DEFAULT))
    st = SimSettings(t_end=float(t_end), dt=float(dt), checkpoint_every=checkpoint_every,
                     **settings)
    sim = Simulation(model, mat, st)
    out_dir = folder / "sim"
    frames_path = out_dir / FRAMES_NAME
    ckpt = _checkpoint_path(out_dir, st)
    fp_settings = {k: v for k, v in asdict(st).items() if k != "checkpoint_every"}
    fingerprint = json.dumps({"model": model.fingerprint(), "material": _material_id(mat),
                              "settings": fp_settings}, sort_keys=True)
    label = folder.name
    if resume and ckpt.exists():
        _resume(sim, ckpt, fingerprint, label, progress)
    say("simulate", label, model.summary(), progress)
    summary = run_simulation(sim, progress=progress, label=label,
                             checkpoint=ckpt if checkpoint_every else None,
                             fingerprint=fingerprint, frames_path=frames_path)
    frames = sim.frames_dict()
    frames["tables_sha256"] = np.array(made_from)
    _atomic_savez(frames_path, frames)
    remove_file(ckpt)
    tc = completion_times(frames)
    summary.update(model.summary())
    summary.update({"completed_cells": int(np.isfinite(tc).sum()),
                    "completion_time_max_s": float(np.nanmax(tc)) if np.isfinite(tc).any()
                    else float("nan"),
                    "frames": str(frames_path)})
    atomic_write_text(out_dir / "summary.json", json_text(summary))
    nc = summary["nonconverged_steps"]
    if nc:
        say("simulate", label, f"WARNING {len(nc)} step(s) did not converge (residual > "
            f"{st.tol:g} N): {nc[:10]}{' ...' if len(nc) > 10 else ''}", progress)
    say("simulate", label, f"{summary['steps']} frames in {summary['wall_s']:.1f} s -> "
        f"sim/{FRAMES_NAME}", progress)
    return summary


def _checkpoint_path(out_dir: Path, st: SimSettings) -> Path:
    """One checkpoint per set of physics options: the build's contact re-run
    (:mod:`pysolver.build`) neither overwrites nor discards the plain run's, so both resume
    (the default physics keeps the plain name)."""
    if st.physics == PHYSICS_DEFAULT:
        return out_dir / CHECKPOINT_NAME
    digest = hashlib.sha256(physics_json(st.physics).encode()).hexdigest()[:12]
    return out_dir / f"checkpoint-{digest}.npz"


def _resume(sim: Simulation, ckpt: Path, fingerprint: str, label: str, progress: bool) -> None:
    """Continue ``sim`` from ``ckpt`` when it was written for the same model, material and
    settings; a damaged or different checkpoint is ignored (the run starts over)."""
    try:
        with np.load(ckpt, allow_pickle=False) as z:
            ok = (int(z["version"]) == CHECKPOINT_VERSION
                  and str(z["fingerprint"]) == fingerprint)
            if ok:
                sim.restore(z)
        say("simulate", label, f"resuming from checkpoint at step {sim.k}" if ok else
            "checkpoint does not match the design/settings; starting over", progress)
    except Exception as e:  # noqa: BLE001 - a damaged checkpoint is ignored, not fatal
        say("simulate", label, f"cannot read checkpoint ({type(e).__name__}); starting over",
            progress)


__all__ = ["SimSettings", "Simulation", "simulate_design", "simulate_model", "run_simulation",
           "membrane_scale", "spring_forces", "check_model_physics", "frozen_rest_lengths",
           "FRAMES_NAME", "CHECKPOINT_NAME"]
