"""Virtual mechanical tests of the morphed, dried shell (SI Note 6).

The shell of a design folder is taken as the simulation left it (the last frame of
``sim/frames.npz``) and dried as the simulator's dry rest does it: every bracket keeps the
force it carried at the end of the morph and meets the dry stiffness beyond it
(:func:`sim.model.simulate.frozen_rest_lengths`), the membrane is back at room temperature.
Unlike the morph, a bumper contact is one-sided here: a closed spring opens when its
bumpers would pull (its total force falls below its bracket's own), an open one closes when
it reaches its contact length (the active set, re-solved within a step).

A test holds real bases with penalty springs (:class:`Holds`): clamps hold a base's pose
(four points), the bending supports and loading nose push on the far faces of the bases
under them, from one side only.  The moving fixture advances in equal steps
(displacement control, quasi-static: one static equilibrium per step, the simulator's
energies and Newton solver); its reaction is the tester's force.

Stresses are effective, as the tester computed them: force over ``a0 b0`` with ``a0`` the
shell's thickness (two printed layers and the membrane) and ``b0`` its width across the
load; bending uses the flexural formulas ``sigma = 3 F L / (2 b0 a0^2)``,
``eps = 6 s a0 / L^2``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from pysolver.core.progress import Steps
from pysolver.errors import InputError
from pysolver.material.bumper import dry_bumper_modulus
from pysolver.mechanics.energies import State, jtkj, spring_terms
from pysolver.mechanics.model import load_model
from pysolver.mechanics.solver import StaticProblem, newton
from pysolver.params import MECHTEST, TESTS, MechTest, PhysicsOptions
from pysolver.tables import read_record, tables_sha256

from .physics import ExternalTerms, bending_stiffness, bumper_stiffness
from .simulate import (
    FRAMES_NAME,
    SimSettings,
    Simulation,
    _resolve_material,
    frozen_rest_lengths,
    membrane_scale,
    spring_forces,
)


def spring_stiffness(coef, x) -> np.ndarray:
    """dF/dx of force coefficients ``coef (n, 4)`` at compressions ``x`` (n,), N/mm."""
    c = np.asarray(coef, float)
    return c[:, 0] + x * (2 * c[:, 1] + x * (3 * c[:, 2] + x * 4 * c[:, 3]))

CONTACT_SLACK_MM = 1e-3
"""Hysteresis of the bumpers' active set, mm: a spring opens once its bumpers would pull by
more than this much contact penetration, and closes this far inside its contact length."""

# ------------------------------------------------------------------------------------------------
# fixtures


class Holds:
    """Penalty springs from points on bases to fixed targets (clamps, supports, a nose).

    Energy ``1/2 d^T K d`` per hold, ``d = p - target`` with ``p = c + R local`` a point of
    a base; a one-sided hold (``normal`` given) acts only while ``d . normal < 0`` with
    ``K = k normal normal^T`` (the point may move away along ``normal``, not into it).

    Parameters
    ----------
    body : (h,) int -- base of each hold
    local : (h, 3) float, mm -- the point in the base's flat frame, from its centre
    target : (h, 3) float, mm
    K : (h, 3, 3) float, N/mm
    normal : (h, 3) float or None -- one-sided direction per hold (zero rows: two-sided)
    """

    def __init__(self, body, local, target, K, normal=None):
        self.body = np.asarray(body, dtype=np.int64)
        self.local = np.asarray(local, float).reshape(-1, 3)
        self.target = np.asarray(target, float).reshape(-1, 3).copy()
        self.K = np.asarray(K, float).reshape(-1, 3, 3)
        n = np.zeros_like(self.local) if normal is None else np.asarray(normal, float)
        self.normal = n.reshape(-1, 3)
        self.one_sided = np.any(self.normal != 0.0, axis=1)

    def points(self, state: State):
        """Held points ``(h, 3)`` and their rotated offsets ``v = R local``."""
        v = np.einsum("hij,hj->hi", state.R[self.body], self.local)
        return state.c[self.body] + v, v

    def gradients(self, state: State) -> np.ndarray:
        """``K d`` per hold (h, 3), N: minus the force each hold puts on the shell."""
        P, _ = self.points(state)
        d = P - self.target
        active = ~self.one_sided | (np.einsum("hi,hi->h", d, self.normal) < 0.0)
        return np.where(active[:, None], np.einsum("hij,hj->hi", self.K, d), 0.0)

    def evaluate(self, state, X, G, hessian: bool):
        """Energy (N mm), gradient per base (m, 6) and Hessian blocks (m, 6, 6) or None, as
        :meth:`sim.model.physics.ExternalTerms.evaluate` (``X``, ``G`` unused)."""
        del X, G
        m = len(state.c)
        P, v = self.points(state)
        gp = self.gradients(state)
        E = 0.5 * float(np.einsum("hi,hi->", gp, P - self.target))
        gb = np.zeros((m, 6))
        tq = np.cross(v, gp)
        for d in range(3):
            gb[:, d] = np.bincount(self.body, gp[:, d], m)
            gb[:, 3 + d] = np.bincount(self.body, tq[:, d], m)
        if not hessian:
            return E, gb, None
        on = np.any(gp != 0.0, axis=1) | ~self.one_sided
        K = np.where(on[:, None, None], self.K, 0.0)
        blk = jtkj(np.ascontiguousarray(K), v, v)
        gv = gp[:, :, None] * v[:, None, :]
        blk[:, 3:, 3:] += 0.5 * (gv + np.transpose(gv, (0, 2, 1))) - np.einsum(
            "hi,hi->h", gp, v)[:, None, None] * np.eye(3)
        Hb = np.zeros((m, 6, 6))
        np.add.at(Hb, self.body, blk)
        return E, gb, Hb

    def energy(self, state, X) -> float:
        return self.evaluate(state, X, None, False)[0]


# ------------------------------------------------------------------------------------------------
# the dried shell


@dataclass
class DryShell:
    """The morphed shell, dried, ready to be loaded.

    Attributes
    ----------
    sim : Simulation -- its energy (dry springs set), solver and model
    state : State -- the dry equilibrium, free of any fixture
    rest_open, coef_open : (s,) float mm, (s, 4) float -- dry bracket springs (frozen load)
    contact_k : (s,) float, N/mm -- bumper contact stiffness per spring
    closed : (s,) bool -- springs at their bumpers
    a0 : float, mm -- the shell's thickness (two layers and the membrane)
    """

    sim: Simulation
    state: State
    rest_open: np.ndarray
    coef_open: np.ndarray
    contact_k: np.ndarray
    closed: np.ndarray
    a0: float
    info: dict = field(default_factory=dict)

    @property
    def model(self):
        return self.sim.model

    def set_springs(self, closed: np.ndarray) -> None:
        """Rest lengths and force laws for the active set ``closed``."""
        md = self.model
        self.closed = np.asarray(closed, bool)
        rest = np.where(self.closed, md.spring_collision, self.rest_open)
        coef = np.where(self.closed[:, None], 0.0, self.coef_open)
        coef[self.closed, 0] = self.contact_k[self.closed]
        self.sim.energy.spring_rest, self.sim.energy.spring_coef = rest, coef

    def lengths(self, state: State) -> np.ndarray:
        return self.sim.spring_lengths(state)

    def bracket_forces(self, L: np.ndarray) -> np.ndarray:
        """The dry brackets' own force at lengths ``L`` (N, compression positive)."""
        return spring_forces(self.coef_open, self.rest_open - L)

    def next_closed(self, state: State) -> np.ndarray:
        """The active set after a solve: closed springs whose bumpers would pull open, open
        ones at or inside their contact length close."""
        L, Lc = self.lengths(state), self.model.spring_collision
        slack = self.contact_k * CONTACT_SLACK_MM  # hysteresis: no chatter at the switch
        total = self.contact_k * (Lc - L)
        stay = self.closed & (total >= self.bracket_forces(L) - slack)
        return stay | (~self.closed & (L < Lc - CONTACT_SLACK_MM))


def _final_state(model, z) -> State:
    """The last frame of ``frames.npz`` as a :class:`State`."""
    inv = np.full(model.n_points, -1, dtype=np.int64)
    inv[model.mem_point] = np.arange(len(model.mem_point))
    f = np.asarray(z["membrane_vertices"][-1])[inv[model.free_points]]
    return State(np.array(z["base_center"][-1]), np.array(z["base_rotation"][-1]), f)


def _frames(folder: Path) -> dict:
    path = folder / "sim" / FRAMES_NAME
    if not path.is_file():
        raise InputError(f"{path} is missing: the mechanical tests load the morphed shell",
                         fix=f"simulate it first: morphshell simulate {folder} (or make "
                             "mechtest shape=..., which builds it)")
    with np.load(path, allow_pickle=False) as z:
        keys = ("t", "base_center", "base_rotation", "membrane_vertices", "bracket_length",
                "collided", "physics")
        missing = [k for k in keys if k not in z.files]
        if missing or len(z["t"]) < 2:
            raise InputError(f"{path} has no morph to load (missing {missing or 'frames'})",
                             fix=f"re-run morphshell simulate {folder}")
        made = str(z["tables_sha256"]) if "tables_sha256" in z.files else None
        out = {k: np.array(z[k]) for k in keys}
    if made is not None and made != tables_sha256(folder):
        raise InputError(f"{path} was simulated from other tables than the folder's now",
                         fix=f"re-run morphshell simulate {folder}")
    return out


def recorded_material(design_dir, options: dict | None = None) -> Path | None:
    """The bracket model file the build of ``design_dir`` ran with (``summary.json``'s
    ``options.material``, as ``morphshell build --material`` recorded it; or ``options``,
    the build's options while it runs, before its summary is written), or ``None`` for
    the committed model (no record, or none given).

    Raises
    ------
    InputError
        The recorded value is not a path string, or names no file (moved or deleted).
    """
    folder = Path(design_dir)
    where = f"{folder / 'summary.json'}" if options is None else "the build's options"
    if options is None:
        rec = read_record(folder / "summary.json")
        options = rec.get("options") if isinstance(rec, dict) else None
    value = options.get("material") if isinstance(options, dict) else None
    if value is None or value == "":
        return None
    fix = ("pass the model file with --material FILE, or rebuild the folder with "
           "'morphshell build ... --material FILE'")
    if not isinstance(value, str) or "\0" in value:
        raise InputError(f"{where}: material is {value!r}, not a file path", fix=fix)
    path = Path(value)
    if not path.is_file():
        raise InputError(f"{where}: the build's material model {value} is not a file "
                         "(moved or deleted?)", fix=fix)
    return path


def dried_shell(design_dir, material=None, consts: MechTest = MECHTEST, *,
                settle: bool = True) -> DryShell:
    """The morphed shell of a design folder, dried and at rest (no fixture, no weight).

    Parameters
    ----------
    design_dir : path-like -- a simulated design folder (``sim/frames.npz``)
    material : BracketModel or path-like, optional -- default: the model the build
        recorded (:func:`recorded_material`), else the committed one
    consts : MechTest
    settle : bool
        Solve the dry equilibrium (the last frame is one already but for the membrane's
        temperature and relaxation, when those physics are on); False: the last frame as
        it is (cheap, for the report).

    Returns
    -------
    DryShell
    """
    folder = Path(design_dir)
    z = _frames(folder)
    ph = PhysicsOptions(**json.loads(str(z["physics"])))
    model = load_model(folder, physics=ph)
    if material is None:
        material = recorded_material(folder)
    mat = _resolve_material(material)
    sim = Simulation(model, mat, SimSettings(physics=PhysicsOptions(
        **{**ph.to_dict(), "gravity": False, "dry_rest": False})))
    sim.energy.external = None
    L = z["bracket_length"].reshape(len(z["t"]), -1)
    L0, b, h = model.spring_rest0, model.spring_bracket_length, model.spring_thickness
    eta, t_end = sim.settings.eta, float(z["t"][-1])
    rest_wet = np.minimum(L0, L0 - eta * (L0 - L[:-1].min(axis=0)))  # the plastic update
    f_end = spring_forces(mat.coefficients(h, b, t_end, eta=eta), rest_wet - L[-1])
    coef_dry = np.asarray(mat.coefficients(h, b, 0.0, eta=0.0), float).reshape(-1, 4)
    rest_dry = L[-1] + frozen_rest_lengths(coef_dry, f_end, b)
    kc = (bumper_stiffness(model, dry_bumper_modulus()) if ph.bumper_compliance
          else np.full(len(L0), model.consts.kappa_c))
    if ph.relaxation or ph.membrane_temperature:
        sim.energy.mu_scale = membrane_scale(ph, t_end + 60.0 * ph.drying_min, wet=False)
    if sim.energy.bending is not None:
        sim.energy.bending.k = bending_stiffness(model, coef_dry[:, 0])
    shell = DryShell(sim, _final_state(model, z), rest_dry, coef_dry, kc,
                     z["collided"][-1].reshape(-1).astype(bool),
                     2 * model.unit.layer_h + model.consts.membrane_h / model.consts.tau**2,
                     {"t_end_s": t_end, "physics": ph.switched_on(),
                      "material": ("committed" if material is None else str(material)
                                   if isinstance(material, str | Path) else type(mat).__name__),
                      "bracket_force_end_N": [float(f_end.min()), float(f_end.max())]})
    if settle:
        shell.state = solve(shell, shell.state, consts)[0]
    return shell


def solve(shell: DryShell, start: State, consts: MechTest = MECHTEST):
    """Static equilibrium from ``start`` with the bumpers' active set updated until it
    settles (at most ``consts.contact_rounds`` solves).

    Returns
    -------
    state : State
    converged : bool -- the last Newton solve converged and the active set settled
    """
    state, ok = start, False
    for _ in range(consts.contact_rounds):
        shell.set_springs(shell.closed)
        problem = StaticProblem(shell.sim.energy, state.copy())
        res = newton(problem, tol=shell.sim.settings.tol, linear=shell.sim.linear,
                     max_iter=shell.sim.settings.max_iter_wet)
        state = problem.state
        state.orthonormalize()
        nxt = shell.next_closed(state)
        settled = bool(np.array_equal(nxt, shell.closed))
        shell.closed = nxt
        ok = bool(res.converged) and settled
        if settled:
            break
    shell.set_springs(shell.closed)
    return state, ok


# ------------------------------------------------------------------------------------------------
# the set-ups


@dataclass
class Setup:
    """One test's fixture and how its readings become a curve.

    Attributes
    ----------
    holds : Holds
    moving : (h,) bool -- holds of the moving fixture
    direction : (3,) float -- its unit direction of motion
    travel : float, mm -- its largest displacement
    x_of, y_of : callable -- displacement (mm) -> curve x; force (N) -> curve y
    columns : tuple of str -- the CSV's header
    bases : dict -- the fixture's bases by role (for ``summary.json``)
    """

    holds: Holds
    moving: np.ndarray
    direction: np.ndarray
    travel: float
    x_of: object
    y_of: object
    columns: tuple
    bases: dict


def _axes(axis_deg: float):
    a = np.deg2rad(axis_deg)
    u = np.array([np.cos(a), np.sin(a), 0.0])
    return u, np.array([-u[1], u[0], 0.0])


def specimen(shell: DryShell, axis_deg: float = 90.0) -> dict:
    """Where the specimen lies: its axis coordinates and width (mm)."""
    u, w = _axes(axis_deg)
    c = shell.state.c
    s, q = c @ u, c @ w
    r = shell.model.unit.base_r
    return {"u": u, "w": w, "s": s - 0.5 * (s.min() + s.max()), "q": q,
            "length": float(np.ptp(s) + 2 * r), "b0": float(np.ptp(q) + 2 * r)}


def _clamp_holds(shell, bases, k):
    r = shell.model.unit.base_r
    local = np.array([[0, 0, 0], [r, 0, 0], [0, r, 0], [0, 0, r]], float)
    body = np.repeat(bases, 4)
    loc = np.tile(local, (len(bases), 1))
    P = shell.state.c[body] + np.einsum("hij,hj->hi", shell.state.R[body], loc)
    return body, loc, P, np.broadcast_to(k * np.eye(3), (len(body), 3, 3))


def setup(shell: DryShell, test: str, axis_deg: float = 90.0,
          consts: MechTest = MECHTEST) -> Setup:
    """The fixture of ``test`` (one of :data:`~pysolver.params.TESTS`) on the dried shell,
    loading along the in-plane direction ``axis_deg`` (deg from the flat x axis)."""
    if test not in TESTS:
        raise InputError(f"unknown test {test!r}", fix=f"use one of {', '.join(TESTS)}")
    sp = specimen(shell, axis_deg)
    s, b0, a0, k = sp["s"], sp["b0"], shell.a0, consts.clamp_stiffness
    area = a0 * b0
    if test == "bend":
        return _bend_setup(shell, sp, consts)
    free = {"stretch": consts.stretch_length, "compress": consts.compress_length,
            "shear": consts.shear_gap}[test]
    lo, hi = np.flatnonzero(s <= -free / 2), np.flatnonzero(s >= free / 2)
    if len(lo) == 0 or len(hi) == 0:
        raise InputError(f"the specimen is {sp['length']:.1f} mm long along the load: too short "
                         f"to clamp outside a free length of {free:g} mm",
                         fix="test a longer design, or turn the load axis (--axis-deg)")
    parts = [_clamp_holds(shell, bases, k) for bases in (lo, hi)]
    body, loc, P, K = (np.concatenate([p[i] for p in parts]) for i in range(4))
    moving = np.r_[np.zeros(4 * len(lo), bool), np.ones(4 * len(hi), bool)]
    holds = Holds(body, loc, P, K)
    bases = {"fixed": lo.tolist(), "moving": hi.tolist()}
    if test == "shear":
        return Setup(holds, moving, sp["w"], consts.shear_max_mm, lambda d: d,
                     lambda f: f / area, ("displacement_mm", "shear_stress_MPa"), bases)
    sign = 1.0 if test == "stretch" else -1.0
    top = consts.stretch_max if test == "stretch" else consts.compress_max
    return Setup(holds, moving, sign * sp["u"], top * free, lambda d: 100 * d / free,
                 lambda f: f / area, ("strain_percent", "stress_MPa"), bases)


def flexural_strain(s, a0: float, span: float):
    """The tester's three-point bending strain ``eps = 6 s a0 / L^2``, in %.

    Parameters
    ----------
    s : float or (n,) float, mm -- the nose's deflection
    a0 : float, mm -- the specimen's thickness
    span : float, mm -- the supports' span ``L``
    """
    return 100 * 6 * np.asarray(s, float) * a0 / span**2


def flexural_stress(force, a0: float, b0: float, span: float):
    """The tester's three-point bending stress ``sigma = 3 F L / (2 b0 a0^2)``, MPa.

    Parameters
    ----------
    force : float or (n,) float, N -- the nose's force
    a0, b0 : float, mm -- the specimen's thickness and width
    span : float, mm -- the supports' span ``L``
    """
    return 3 * np.asarray(force, float) * span / (2 * b0 * a0**2)


def _bend_setup(shell, sp, consts: MechTest) -> Setup:
    s, b0, a0, span = sp["s"], sp["b0"], shell.a0, consts.bend_span
    r, h = shell.model.unit.base_r, shell.model.unit.layer_h
    if sp["length"] < span + 2 * r:
        raise InputError(f"the specimen is {sp['length']:.1f} mm long along the load: shorter "
                         f"than the bending span {span:g} mm",
                         fix="test a longer design, or turn the load axis (--axis-deg)")
    # the row of bases nearest each line (and any within half a radius of it): a support
    # or the nose touches the bases whose far faces lie over it
    dist = [np.abs(s - x) for x in (-span / 2, span / 2, 0.0)]
    rows = [np.flatnonzero(d <= d.min() + r / 2) for d in dist]
    sup, nose = np.r_[rows[0], rows[1]], rows[2]
    k, z = consts.clamp_stiffness, np.array([0.0, 0.0, 1.0])
    zz = np.outer(z, z)
    c, R = shell.state.c, shell.state.R
    below, above = np.array([0, 0, -h], float), np.array([0, 0, h], float)
    body = np.r_[sup, nose, nose]
    loc = np.r_[np.tile(below, (len(sup), 1)), np.tile(above, (len(nose), 1)),
                np.zeros((len(nose), 3))]
    P = c[body] + np.einsum("hij,hj->hi", R[body], loc)
    K = np.r_[np.broadcast_to(k * zz, (len(body) - len(nose), 3, 3)),
              np.broadcast_to(consts.stabiliser_N_mm * (np.eye(3) - zz), (len(nose), 3, 3))]
    normal = np.r_[np.tile(z, (len(sup), 1)), np.tile(-z, (len(nose), 1)),
                   np.zeros((len(nose), 3))]
    moving = np.r_[np.zeros(len(sup), bool), np.ones(len(nose), bool),
                   np.zeros(len(nose), bool)]
    travel = consts.bend_max * span**2 / (6 * a0)
    return Setup(Holds(body, loc, P, K, normal), moving, -z, travel,
                 lambda d: flexural_strain(d, a0, span),
                 lambda f: flexural_stress(f, a0, b0, span),
                 ("strain_percent", "stress_MPa"), {"supports": sup.tolist(),
                                                   "nose": nose.tolist()})


# ------------------------------------------------------------------------------------------------
# running a test


def _energy_parts(shell: DryShell, state: State) -> dict:
    """Energy (N mm) in the bumper contacts, the brackets and the membrane."""
    md, en = shell.model, shell.sim.energy
    X, _ = en.positions(state)
    sp_ = md.spring_points
    e = spring_terms(X[sp_[:, 0]], X[sp_[:, 1]], en.spring_rest, en.spring_coef,
                     hessian=False)[0]
    parts = en.energy_parts(state)
    return {"bumper contact": float(e[shell.closed].sum()),
            "brackets": float(e[~shell.closed].sum()) + parts["cross"]
            + parts.get("bending", 0.0),
            "membrane": parts["membrane"]}


def run_test(shell: DryShell, test: str, *, axis_deg: float = 90.0,
             consts: MechTest = MECHTEST, progress: bool = True, label: str = "") -> dict:
    """Load the dried shell as the tester did; the curve and its readings.

    Returns
    -------
    dict
        ``columns``; ``x``, ``y`` (steps + 1,) the curve; ``force_N``, ``displacement_mm``;
        ``converged`` (steps + 1,) bool; ``open_cells``, ``yielded`` per step; ``energy``
        per step and part (N mm); ``bases`` of the fixture; ``b0``, ``a0`` mm.
    """
    st = setup(shell, test, axis_deg, consts)
    closed0 = shell.closed.copy()
    shell.sim.energy.external = st.holds
    target0 = st.holds.target.copy()
    state = shell.state.copy()
    n, stopped = consts.steps, None
    rows = {"displacement_mm": [], "force_N": [], "converged": [], "open_cells": [],
            "max_bracket_N": [], "energy": []}
    steps = Steps("mechtest", f"{label} {test}".strip(), n + 1, enabled=progress, every_s=2.0)
    try:
        for i in range(n + 1):
            d = st.travel * i / n
            st.holds.target = target0 + np.where(st.moving[:, None], d * st.direction, 0.0)
            trial, ok = solve(shell, state, consts)
            g = st.holds.gradients(trial)[st.moving]
            force = float(-(g @ st.direction).sum())
            if _lost(force, ok, rows):
                stopped = f"the solve failed at {st.columns[0]} {st.x_of(d):.3g}"
                steps.step(f"stopped: {stopped}", k=n + 1)
                break
            state = trial
            L = shell.lengths(state)
            cells_open = (~shell.closed & closed0).reshape(-1, 4)
            for key, val in (("displacement_mm", d), ("force_N", force), ("converged", ok),
                             ("open_cells", int(np.any(cells_open, axis=1).sum())),
                             ("max_bracket_N", float(np.abs(shell.bracket_forces(L)).max())),
                             ("energy", _energy_parts(shell, state))):
                rows[key].append(val)
            steps.step(f"{st.columns[0]} {st.x_of(d):.3g}  force {force:.3g} N")
    finally:
        shell.sim.energy.external = None
        shell.closed = closed0
        shell.set_springs(closed0)
    disp = np.array(rows["displacement_mm"])
    force = np.array(rows["force_N"])
    return {**rows, "test": test, "columns": st.columns, "x": st.x_of(disp),
            "y": st.y_of(force), "displacement_mm": disp, "force_N": force,
            "bases": st.bases, "a0": shell.a0, "stopped": stopped,
            "b0": specimen(shell, axis_deg)["b0"], "axis_deg": axis_deg}


def _lost(force: float, ok: bool, rows: dict) -> bool:
    """A step the test cannot keep: a non-finite force, or one that did not converge and
    follows another that did not, or jumps past ten times the largest force so far."""
    if not np.isfinite(force):
        return True
    if ok:
        return False
    scale = max((abs(f) for f in rows["force_N"]), default=0.0)
    return (bool(rows["converged"]) and not rows["converged"][-1]) or (
        scale > 0 and abs(force) > 10 * scale)


def readings(curve: dict, consts: MechTest = MECHTEST) -> dict:
    """``initial_slope``, ``peak_stress_MPa``, ``peak_at`` and ``limit`` of a test's curve.

    The peak is read up to the first step whose largest bracket force passes
    ``consts.bracket_yield_N`` (then ``limit`` is ``bracket yield``); else over the whole
    range, and ``limit`` names what stores most of the work done up to the peak
    (``bumper contact``, ``brackets`` or ``membrane``).
    """
    x, y = np.asarray(curve["x"], float), np.asarray(curve["y"], float)
    base = np.asarray(curve["max_bracket_N"], float)
    over = np.flatnonzero(base > max(consts.bracket_yield_N, base[0]))
    end = int(over[0]) if len(over) else len(x) - 1
    k = int(np.argmax(y[: end + 1]))
    e0, ek = curve["energy"][0], curve["energy"][k]
    share = {key: ek[key] - e0[key] for key in e0}
    limit = "bracket yield" if len(over) else max(share, key=share.get)
    return {"initial_slope": initial_slope(x, y, curve["test"], consts),
            "peak_stress_MPa": float(y[k]), "peak_at": float(x[k]), "limit": limit,
            "work_share_Nmm": share, "yield_step": end if len(over) else None}


def initial_slope(x, y, test: str, consts: MechTest = MECHTEST) -> float:
    """Least-squares slope of ``y`` against ``x`` over the first ``slope_window`` of strain
    (percent; shear: ``10 slope_window`` mm), MPa per % or MPa per mm."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    w = 10 * consts.slope_window if test == "shear" else 100 * consts.slope_window
    sel = (x >= 0) & (x <= w)
    if sel.sum() < 2:
        sel = np.arange(len(x)) < 2
    return float(np.polyfit(x[sel], y[sel], 1)[0])


# ------------------------------------------------------------------------------------------------
# what the shell bears (the report's section)


def _up(shell: DryShell) -> np.ndarray:
    """The shell's up: the mean of its bases' top normals (+z of a flat shell)."""
    n = shell.state.R[:, :, 2].mean(axis=0)
    norm = np.linalg.norm(n)
    return n / norm if norm > 1e-6 else np.array([0.0, 0.0, 1.0])


def _stand(shell: DryShell, up: np.ndarray):
    """The shell standing on its rim: the rim's lowest bases (bases with fewer than three
    cells, within a base radius of the lowest of them), the base under a point load (the
    highest; of several, the nearest the centre), and for each the local offset of its face
    towards the table or the load."""
    md = shell.model
    c, R = shell.state.c, shell.state.R
    r, h = md.unit.base_r, md.unit.layer_h
    height = c @ up
    rim = np.flatnonzero(np.bincount(md.cell_bases.ravel(), minlength=md.n_bases) < 3)
    low = rim[height[rim] <= height[rim].min() + r]
    inner = np.setdiff1d(np.arange(md.n_bases), low)
    top = inner[height[inner] >= height[inner].max() - r]
    flat = c - np.outer(height, up)
    apex = int(top[np.argmin(np.linalg.norm(flat[top] - flat.mean(axis=0), axis=1))])
    side = np.sign(np.einsum("mi,i->m", R[:, :, 2], up))
    side[side == 0] = 1.0
    return low, apex, np.c_[np.zeros((len(c), 2)), h * side]


def bearing(shell: DryShell, consts: MechTest = MECHTEST) -> dict:
    """What the dried shell bears, standing on the lowest bases of its rim, to first order
    (one factorisation: cheap enough for every report).

    A point load on the apex (the highest inner base; of several, the nearest the centre)
    and the shell's own weight (``sim.model.physics.ExternalTerms``, dry) are applied to the
    dry shell's stiffness at its resting state, the supports holding the rim along the
    vertical.  From the displacement per newton: the stiffness (N/mm) and the load at which
    the first closed cell's bumpers come apart, or the first bracket passes
    ``consts.bracket_yield_N`` (linear extrapolations).

    Returns
    -------
    dict -- ``point_stiffness_N_per_mm``, ``cell_opens_N``, ``bracket_limit_N``,
    ``weight_N``, ``weight_sag_mm`` (the largest sag under the weight),
    ``weight_stiffness_N_per_mm`` (weight over that sag), ``apex_base``, ``n_supports``
    """
    md, en, state = shell.model, shell.sim.energy, shell.state
    up = _up(shell)
    low, apex, face = _stand(shell, up)
    uu, soft = np.outer(up, up), consts.stabiliser_N_mm
    body = np.r_[low, low]
    loc = np.r_[-face[low], np.zeros((len(low), 3))]
    P = state.c[body] + np.einsum("hij,hj->hi", state.R[body], loc)
    K = np.r_[np.broadcast_to(consts.clamp_stiffness * uu, (len(low), 3, 3)),
              np.broadcast_to(soft * (np.eye(3) - uu), (len(low), 3, 3))]
    shell.set_springs(shell.closed)
    en.external = Holds(body, loc, P, K)
    try:
        _, g0, H = en.evaluate(state, hessian=True)
    finally:
        en.external = None
    A = (H + H.T - sp.diags(H.diagonal())).tocsc()
    f = np.zeros((2, md.n_dof))
    v = state.R[apex] @ face[apex]
    f[0, 6 * apex: 6 * apex + 3] = -up
    f[0, 6 * apex + 3: 6 * apex + 6] = np.cross(v, -up)
    weight = ExternalTerms(md, PhysicsOptions(), wet=False, plane=False)
    gw = np.zeros(md.n_dof)
    X, _ = en.positions(state)
    Gp = np.zeros((md.n_points, 3))
    gw[: 6 * md.n_bases] = weight.evaluate(state, X, Gp, False)[1].ravel()
    gw[6 * md.n_bases:] = Gp[md.free_points].ravel()
    f[1] = -gw
    u = spla.splu(A).solve(f.T).T  # mm (and rad) per N, per the weight
    sag_point = -float(u[0, 6 * apex: 6 * apex + 3] @ up)
    sag_w = state.moved(u[1])
    drop = (state.c - sag_w.c) @ up
    W = weight.weight_total()
    opens, limit = _first_events(shell, state, u[0], consts)
    return {"point_stiffness_N_per_mm": 1.0 / sag_point if sag_point > 0 else None,
            "cell_opens_N": opens, "bracket_limit_N": limit, "weight_N": W,
            "weight_sag_mm": float(drop.max()),
            "weight_stiffness_N_per_mm": W / float(drop.max()) if drop.max() > 0 else None,
            "apex_base": apex, "n_supports": len(low)}


def _first_events(shell: DryShell, state: State, du: np.ndarray, consts: MechTest):
    """Loads (N) at which, extrapolating the displacement ``du`` per newton, a closed
    spring's bumpers first come apart and an open bracket first passes its tested load."""
    eps = 1e-3
    L0 = shell.lengths(state)
    dL = (shell.lengths(state.moved(du, eps)) - L0) / eps  # mm per N
    Lc, kc = shell.model.spring_collision, shell.contact_k
    fb = shell.bracket_forces(L0)
    kb = spring_stiffness(shell.coef_open, shell.rest_open - L0)
    bump = kc * (Lc - L0) - fb  # the bumpers' own force, N (compression +)
    dbump = (-kc + kb) * dL
    c = shell.closed & (dbump < 0)
    opens = float((bump[c] / -dbump[c]).min()) if c.any() else None
    dfb = -kb * dL
    o = ~shell.closed & (np.abs(dfb) > 0)
    room = consts.bracket_yield_N - np.abs(fb[o])
    grow = np.abs(fb[o] + dfb[o]) - np.abs(fb[o])  # growth of |F| per N
    ok = grow > 0
    limit = float((np.maximum(room[ok], 0.0) / grow[ok]).min()) if ok.any() else None
    return (None if opens is None else max(opens, 0.0)), limit

__all__ = ["Holds", "DryShell", "dried_shell", "recorded_material", "solve", "Setup", "setup",
           "specimen", "flexural_strain", "flexural_stress", "run_test", "readings",
           "initial_slope", "bearing"]
