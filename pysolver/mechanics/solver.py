"""Newton's method for the static equilibrium of the shell.

Design (documented choices):

* **Linear solver.**  CHOLMOD supernodal LL^T (scikit-sparse) on the lower triangle of the
  reduced Hessian; the symbolic analysis is done once per sparsity pattern (the pattern is
  fixed by :class:`.energies.SparsePattern`) and reused, each Newton iteration only
  refactorises.  Debian's CHOLMOD starts OpenMP threads regardless of ``OMP_NUM_THREADS``;
  ``OMP_THREAD_LIMIT=1`` is set before importing it (2-3x faster on 2 cores; it must be set
  before any library loads OpenMP, so entry points import this module first).  CHOLMOD's
  dense supernode kernels call Debian's OpenBLAS, whose pthreads (two on this machine, three
  OpenBLAS copies in one process: numpy's, scipy's, Debian's) cost far more in wake-ups than
  they gain on these small blocks: a 11055-DOF factorisation takes 9-12 ms on one thread and
  44-200 ms with the default threads, worse when the other core is busy.  So every CHOLMOD
  call runs with one BLAS thread (threadpoolctl, scoped to the call, 0.05 ms), unless the
  user set ``OPENBLAS_NUM_THREADS``.  If
  scikit-sparse is missing or CHOLMOD fails for another reason than indefiniteness, scipy
  SuperLU (``MMD_AT_PLUS_A`` ordering, ``SymmetricMode``, no pivoting) takes over; a
  non-positive pivot there counts as "not positive definite".
* **Regularisation.**  The reduced Hessian has an exact 3-D null space (global translation:
  nothing is pinned) and near-null rotations, and it becomes indefinite where the shell is
  about to buckle or snap.  Every solve adds ``r D`` (``D`` = 1 for translations, ``base_r^2``
  for rotations, ``r`` relative to the mean of ``diag H / D``).  ``r`` starts at 1e-8 and is
  adapted (Nocedal & Wright 3.4): x4 while the factorisation reports "not positive definite",
  the direction does not descend or the line search fails; the next iteration starts at a
  quarter of the value that worked.  So the shift stays just above the most negative
  curvature and the step follows the instability instead of creeping.  Beyond ``r = 1`` the
  per-element convexified Hessian (PSD projection) is used, and as a last resort a diagonally
  scaled gradient step.
* **Line search.**  Strong Wolfe (``c1 = 1e-4``, ``c2 = 0.9``; Nocedal & Wright Alg. 3.5/3.6
  with bisection zoom), as in SI Note 2.  It tries ``alpha = 1`` first (so Newton keeps its
  quadratic convergence) and *expands* the step while the slope is still steep (negative
  curvature).  Near convergence, energy differences fall below the round-off of a sum of
  thousands of element energies, so sufficient decrease is tested up to that round-off
  (``1e-13`` x the sum of |element energies|) and the curvature condition, which uses the
  accurate gradient, decides.  Steps are capped so no base centre or vertex moves more than
  ``max_step_mm`` (2 mm) and no base turns more than ``max_rot_rad`` (0.3 rad) per iteration.
* **Convergence.**  ``residual = max(|forces|_inf, |torques|_inf / base_r)`` (N) below
  ``tol.newton_grad`` (1e-6 N): forces on base centres and free membrane vertices in N,
  torques in N mm divided by the base radius (the equivalent force at the base rim).  A solve
  that stops otherwise reports ``converged = False`` with its status (``max_iter``,
  ``line_search``, ``nan``); the caller decides (the time stepper records and reports it).
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import os
import time
import warnings
from dataclasses import dataclass, field

_USER_OMP_LIMIT = "OMP_THREAD_LIMIT" in os.environ
_USER_BLAS_LIMIT = "OPENBLAS_NUM_THREADS" in os.environ
os.environ.setdefault("OMP_THREAD_LIMIT", "1")

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402
from threadpoolctl import ThreadpoolController  # noqa: E402

from pysolver.errors import InputError  # noqa: E402
from pysolver.params import NEWTON  # noqa: E402
from pysolver.params import tol as TOL  # noqa: E402

from .energies import ShellEnergy, State, full_from_lower  # noqa: E402

try:  # soft dependency: scikit-sparse
    from sksparse.cholmod import CholmodNotPositiveDefiniteError, analyze

    HAVE_CHOLMOD = True
except ImportError:  # pragma: no cover - depends on the installation
    HAVE_CHOLMOD = False
    CholmodNotPositiveDefiniteError = RuntimeError


def _limit_openmp() -> None:
    """One OpenMP thread for CHOLMOD even if libgomp was initialised before the environment
    variable was set (another module imported scikit-sparse first): ``omp_set_num_threads(1)``
    on the calling thread, which is the one that calls CHOLMOD.  A user's own
    ``OMP_THREAD_LIMIT`` is respected."""
    if _USER_OMP_LIMIT or not HAVE_CHOLMOD:
        return

    try:
        ctypes.CDLL("libgomp.so.1").omp_set_num_threads(1)
    except (OSError, AttributeError):  # pragma: no cover - no GNU OpenMP runtime
        pass


_limit_openmp()

# the BLAS libraries loaded now, CHOLMOD's among them (scikit-sparse is imported above)
_BLAS = None if _USER_BLAS_LIMIT else ThreadpoolController()


def _one_blas_thread():
    """Context in which every loaded BLAS runs one thread (see the module docstring)."""
    if _BLAS is None:
        return contextlib.nullcontext()
    return _BLAS.limit(limits=1, user_api="blas")


def _blas_scoped(fn):
    """Decorator of :func:`newton`: the whole solve runs in its linear solver's BLAS scope
    (numpy's vector norms and dot products pay the same thread wake-ups as CHOLMOD)."""
    @functools.wraps(fn)
    def wrapped(problem, *args, linear=None, **kwargs):
        linear = linear or LinearSolver()
        with linear.blas_scope():
            return fn(problem, *args, linear=linear, **kwargs)

    return wrapped


BACKENDS = ("auto", "cholmod", "superlu")
SOLVERS = ("fast", "reference")
"""``fast``: one BLAS thread in every solve (the default); ``reference``: the thread pools as
the libraries set them, the path before this was measured (kept for ``make bench``)."""


class NotPositiveDefinite(Exception):
    """The matrix handed to :class:`LinearSolver` is not positive definite."""


class LinearSolver:
    """Symmetric positive definite sparse solver with a cached symbolic analysis.

    Parameters
    ----------
    backend : {"auto", "cholmod", "superlu"}
        ``auto`` = CHOLMOD if scikit-sparse is importable, else SuperLU.
    """

    def __init__(self, backend: str = "auto", solver: str = "fast"):
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        if solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
        self.solver = solver
        if backend == "cholmod" and not HAVE_CHOLMOD:

            raise InputError("backend 'cholmod' needs scikit-sparse",
                             fix="apt-get install libsuitesparse-dev; pip install "
                                 "scikit-sparse==0.4.16 (or use backend='superlu')")
        self.backend = "cholmod" if backend == "auto" and HAVE_CHOLMOD else backend
        if self.backend == "auto":
            self.backend = "superlu"
        self._factor = None
        self._pattern_key = None
        self._lu = None
        self.n_factorizations = 0
        self.n_analyses = 0
        self.factorize_s = 0.0
        self.solve_s = 0.0
        self.shift_hint = NEWTON.shift_min

    def blas_scope(self):
        """Context for the calls of this solver: one BLAS thread (``fast``), or nothing."""
        return _one_blas_thread() if self.solver == "fast" else contextlib.nullcontext()

    def timings(self) -> dict:
        """Counters since construction: factorisations, analyses, and their wall times (s)."""
        return {"factorizations": self.n_factorizations, "analyses": self.n_analyses,
                "factorize_s": round(self.factorize_s, 4), "solve_s": round(self.solve_s, 4)}

    def factorize(self, A_lower: sp.csc_matrix) -> None:
        """Factorise the SPD matrix given by its lower triangle (CSC, sorted indices).

        Raises
        ------
        NotPositiveDefinite
            CHOLMOD found a non-positive pivot (SuperLU: a non-positive diagonal pivot).
        """
        self.n_factorizations += 1
        t0 = time.perf_counter()
        try:
            with self.blas_scope():
                self._factorize(A_lower)
        finally:
            self.factorize_s += time.perf_counter() - t0

    def _factorize(self, A_lower: sp.csc_matrix) -> None:
        if self.backend == "cholmod":
            key = (A_lower.shape, A_lower.indptr.tobytes(), A_lower.indices.tobytes())
            try:
                if self._factor is None or key != self._pattern_key:
                    self._factor = analyze(A_lower, mode="supernodal")
                    self._pattern_key = key
                    self.n_analyses += 1
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    self._factor.cholesky_inplace(A_lower)
                return
            except CholmodNotPositiveDefiniteError:
                raise NotPositiveDefinite from None
            except Exception:  # noqa: BLE001 - any other CHOLMOD failure: fall back
                warnings.warn("CHOLMOD failed; falling back to SuperLU", RuntimeWarning,
                              stacklevel=2)
                self.backend = "superlu"
        full = full_from_lower(A_lower)
        try:
            self._lu = spla.splu(full, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                 options={"SymmetricMode": True})
        except RuntimeError as e:  # exactly singular
            raise NotPositiveDefinite(str(e)) from None
        d = self._lu.U.diagonal()
        if np.any(~np.isfinite(d)) or np.any(d <= 0):
            raise NotPositiveDefinite("non-positive pivot")

    def solve(self, b: np.ndarray) -> np.ndarray:
        """Solve with the last factorisation; ``b`` : (n,) or (n, k) float."""
        t0 = time.perf_counter()
        with self.blas_scope():
            x = self._factor(b) if self.backend == "cholmod" else self._lu.solve(b)
        self.solve_s += time.perf_counter() - t0
        return x


@dataclass
class NewtonResult:
    """Outcome of one static solve.

    Attributes
    ----------
    converged : bool
    status : str
        ``converged``, ``max_iter``, ``line_search`` (no acceptable step) or ``nan``.
    iterations : int
    residual : float, N
    energy : float, N mm
    regularised : int
        Iterations that needed the convexified Hessian or a larger shift.
    gradient_steps : int
        Iterations that fell back to a scaled gradient step.
    history : list of (energy, residual, alpha)
    wall_s : float
    """

    converged: bool
    status: str
    iterations: int
    residual: float
    energy: float
    regularised: int = 0
    gradient_steps: int = 0
    history: list = field(default_factory=list)
    wall_s: float = 0.0


class StaticProblem:
    """Equilibrium of a :class:`ShellEnergy` starting from ``state`` (updated in place)."""

    def __init__(self, energy: ShellEnergy, state: State):
        self.energy = energy
        self.state = state
        self.n = energy.n
        self.dof_scale = energy.dof_scale
        self.trans_dofs, self.rot_dofs = energy.trans_dofs, energy.rot_dofs
        self._scale = None  # (state, energy scale) of the last evaluation

    def evaluate(self, hessian=True, psd=False):
        out = self.energy.evaluate(self.state, hessian=hessian, psd=psd)
        self._scale = (self.state, self.energy.last_energy_scale)
        return out

    def trial(self, dx, alpha):
        return self.state.moved(dx, alpha)

    def energy_at(self, trial) -> float:
        return self.energy.energy(trial)

    def gradient_at(self, trial):
        return self.energy.gradient(trial)

    def accept(self, trial) -> None:
        self.state = trial

    def step_limit(self, p, alpha_max: float) -> float:
        """``alpha_max``, or the collision-free fraction of it (contact barriers)."""
        return self.energy.step_limit(self.state, p, alpha_max)

    def residual(self, g) -> float:
        return self.energy.residual(g)

    def roundoff(self) -> float:
        """Round-off of the energy at the current state (1e-13 x the sum of |energy parts|);
        free when the current state was the last one evaluated."""
        scale = (self._scale[1] if self._scale is not None and self._scale[0] is self.state
                 else self.energy.energy_scale(self.state))
        return TOL.energy_roundoff * max(scale, 1.0)


def _step_limit(p, trans, rot, max_step, max_rot) -> float:
    """Largest multiplier of ``p`` keeping every translation <= max_step, rotation <= max_rot."""
    t = np.abs(p[trans]).max(initial=0.0)
    r = np.linalg.norm(p[rot].reshape(-1, 3), axis=1).max(initial=0.0)
    return min(max_step / t if t > 0 else np.inf, max_rot / r if r > 0 else np.inf)


def _wolfe(problem, p, E0, g0, eps_E, alpha_max, c1, c2, max_evals):
    """Strong Wolfe line search along ``p`` (Nocedal & Wright, Alg. 3.5/3.6, bisection zoom).

    Sufficient decrease is tested up to the energy's round-off ``eps_E``:
    ``E(a) <= E0 + c1 a g0.p + eps_E``; curvature ``|g(a).p| <= c2 |g0.p|``.  Steps expand
    (doubling, up to ``alpha_max``) while the slope is still steep, which lets the solver move
    along directions of negative curvature instead of creeping.

    Returns
    -------
    alpha : float
    trial : state at ``alpha`` (None when no acceptable step was found)
    ok : bool
    E, g : float, N mm and (n,) float
        Energy and gradient at ``trial`` (evaluated by the search; None when not ok), so
        the caller need not evaluate them again.
    """
    d0 = float(g0 @ p)
    if not d0 < 0:
        return 0.0, None, False, None, None
    evals = 0
    best = None  # (alpha, trial, E, g) with sufficient decrease
    last = None  # gradient at the last trial

    def phi(a):
        nonlocal evals, last
        evals += 1
        tr = problem.trial(p, a)
        Et, last = problem.gradient_at(tr)
        return tr, Et, float(last @ p) if np.all(np.isfinite(last)) else np.nan

    def done(a, tr, Et, gt=None):
        return a, tr, True, Et, last if gt is None else gt

    def armijo(a, Et):
        return np.isfinite(Et) and Et <= E0 + c1 * a * d0 + eps_E

    def zoom(lo, E_lo, hi):
        nonlocal best
        while evals < max_evals:
            a = 0.5 * (lo + hi)
            tr, Et, dt = phi(a)
            if not armijo(a, Et) or Et >= E_lo + eps_E:
                hi = a
            else:
                if best is None or Et < best[2]:
                    best = (a, tr, Et, last)
                if abs(dt) <= -c2 * d0:
                    return done(a, tr, Et)
                if dt * (hi - lo) >= 0:
                    hi = lo
                lo, E_lo = a, Et
            if abs(hi - lo) < TOL.exact * max(lo, hi, TOL.tiny):
                break
        if best is not None:
            return done(*best)
        return 0.0, None, False, None, None

    a_prev, E_prev = 0.0, E0
    a = min(1.0, alpha_max)
    while evals < max_evals:
        tr, Et, dt = phi(a)
        if not armijo(a, Et) or (a_prev > 0 and Et >= E_prev + eps_E) or not np.isfinite(dt):
            return zoom(a_prev, E_prev, a)
        if best is None or Et < best[2]:
            best = (a, tr, Et, last)
        if abs(dt) <= -c2 * d0:
            return done(a, tr, Et)
        if dt >= 0:
            return zoom(a, Et, a_prev)
        if a >= alpha_max:
            return done(a, tr, Et)
        a_prev, E_prev = a, Et
        a = min(2.0 * a, alpha_max)
    if best is not None:
        return done(*best)
    return 0.0, None, False, None, None




def _candidates(last_shift: float):
    """Search-direction candidates of one Newton iteration, in order.

    Exact Hessian first with the base shift NEWTON.shift_min (pure Newton wherever the Hessian is
    positive definite); if that fails, with an adaptive shift (Nocedal & Wright §3.4 'adding a
    multiple of the identity') starting at a quarter of the shift that worked last time (at
    least 1e-6) and growing x4 while the matrix is not positive definite, the direction is
    not a descent direction or the line search fails, up to NEWTON.shift_max; then the convexified
    Hessian with NEWTON.psd_ladder; then a scaled gradient step.
    """
    yield "exact", NEWTON.shift_min
    s = max(last_shift / 4.0, NEWTON.shift_floor)
    while s <= NEWTON.shift_max:
        yield "exact", s
        s *= 4.0
    for s in NEWTON.psd_ladder:
        yield "psd", s
    yield "gradient", 0.0


@_blas_scoped
def newton(problem, *, tol: float = TOL.newton_grad, max_iter: int = NEWTON.max_iter_wet,
           linear: LinearSolver | None = None, c1: float = NEWTON.armijo_c1,
           c2: float = NEWTON.wolfe_c2, max_halvings: int = NEWTON.line_search_halvings,
           max_step_mm: float = NEWTON.max_step_mm,
           max_rot_rad: float = NEWTON.max_rot_rad, callback=None) -> NewtonResult:
    """Minimise the energy of ``problem`` by Newton's method with line search.

    Each iteration tries search directions from :func:`_candidates` -- the exact Hessian
    plus an adaptive shift ``r D`` (``D`` = 1 for translations, ``base_r^2`` for rotations;
    ``r`` relative to the mean of ``diag H / D``), then the convexified Hessian, then a scaled
    gradient -- until the matrix factorises (positive definite), the direction descends and it
    passes the strong Wolfe line search.  The shift that worked is remembered (in ``linear``)
    and, if the unshifted Hessian is still not positive definite, the next iteration
    continues from a quarter of it: the shift stays just above the most negative curvature
    (a buckling mode) at about two factorisations per iteration, and drops to the base value
    as soon as the Hessian is positive definite again (quadratic convergence).

    Parameters
    ----------
    problem : StaticProblem
        Anything with ``evaluate``, ``trial``, ``energy_at``, ``gradient_at``, ``accept``,
        ``residual``, ``roundoff``, ``n``, ``dof_scale``, ``trans_dofs``, ``rot_dofs``.
    tol : float, N
        Convergence threshold on :meth:`ShellEnergy.residual`.
    max_iter : int
    linear : LinearSolver, optional
        Reused between calls (keeps CHOLMOD's symbolic analysis and the ladder position).
    c1, c2 : float
        Strong Wolfe constants (sufficient decrease, curvature).
    max_halvings : int
        Most energy + gradient evaluations per line search.
    max_step_mm, max_rot_rad : float
        Step caps per iteration.
    callback : callable, optional
        ``callback(iteration, energy, residual)`` after each accepted step.

    Returns
    -------
    NewtonResult
    """
    t0 = time.perf_counter()
    E, g, H = problem.evaluate(hessian=True)
    r = problem.residual(g)
    hist = [(E, r, 0.0)]
    n_reg = n_grad = it = 0
    status, shift = "max_iter", getattr(linear, "shift_hint", NEWTON.shift_min)
    if not np.isfinite(E) or not np.all(np.isfinite(g)):
        return NewtonResult(False, "nan", 0, float("nan"), E, history=hist,
                            wall_s=time.perf_counter() - t0)
    while it < max_iter:
        if r < tol:
            status = "converged"
            break
        it += 1
        st = _iteration(problem, E, g, H, problem.dof_scale, shift, linear,
                        (c1, c2, max_halvings), (max_step_mm, max_rot_rad))
        n_grad += st.gradient
        if not st.accepted:
            status = "line_search"
            break
        n_reg += st.regularised
        problem.accept(st.trial)
        shift = linear.shift_hint = st.shift
        E, g = st.E, st.g  # the search evaluated them at the accepted point
        r = problem.residual(g)
        hist.append((E, r, st.alpha))
        if callback is not None:
            callback(it, E, r)
        if not np.isfinite(E) or not np.all(np.isfinite(g)):
            status = "nan"
            break
        if linear.solver == "reference" or (r >= tol and it < max_iter):
            E, g, H = problem.evaluate(hessian=True)  # (fast: only when another iteration
            # follows; the reference path evaluates after every step, as it used to)
    else:
        if r < tol:
            status = "converged"
    return NewtonResult(status == "converged", status, it, r, E, n_reg, n_grad, hist,
                        time.perf_counter() - t0)


@dataclass
class _Iteration:
    """The outcome of one Newton iteration (:func:`_iteration`)."""

    accepted: bool
    shift: float
    regularised: bool = False
    gradient: bool = False
    trial: object = None
    alpha: float = 0.0
    E: float = float("nan")
    g: np.ndarray | None = None


def _iteration(problem, E, g, H, D, shift: float, linear, wolfe, caps) -> _Iteration:
    """One iteration of :func:`newton`: the search directions of :func:`_candidates` in turn
    until one factorises, descends and passes the strong Wolfe line search.

    Parameters
    ----------
    E, g, H : the energy (N mm), gradient and Hessian at the current point
    D : (n,) float -- the dofs' scale
    shift : float -- the shift that worked last (relative)
    wolfe : (c1, c2, max_halvings)
    caps : (max_step_mm, max_rot_rad)

    Returns
    -------
    _Iteration
        ``accepted`` and the accepted ``trial`` point, step ``alpha``, energy ``E`` and
        gradient ``g`` there; the ``shift`` to start from next; whether the step was
        ``regularised`` (not the exact Hessian at the base shift) and whether the gradient
        step was tried (``gradient``).
    """
    Hpsd = None
    eps_E = problem.roundoff()
    tried_gradient = False
    for kind, rel in _candidates(shift):
        if kind == "gradient":  # last resort: diagonally scaled steepest descent
            p = -g / np.maximum(np.abs(_diag(H)), TOL.exact * _scale(H, D) * D)
            tried_gradient = True
        else:
            if kind == "psd" and Hpsd is None:
                _, _, Hpsd = problem.evaluate(hessian=True, psd=True)
            p = _solve_shifted(Hpsd if kind == "psd" else H, g, D, rel, linear)
            if p is None:
                continue
        alpha_max = _step_limit(p, problem.trans_dofs, problem.rot_dofs, *caps)
        limit = getattr(problem, "step_limit", None)
        if limit is not None:  # contact barriers: the collision-free part of the step
            alpha_max = limit(p, alpha_max)
        alpha, trial, accepted, E_trial, g_trial = _wolfe(problem, p, E, g, eps_E,
                                                          alpha_max, *wolfe)
        if accepted:
            if kind == "exact" and rel > NEWTON.shift_min:
                shift = rel
            return _Iteration(True, shift, not (kind == "exact" and rel <= NEWTON.shift_min),
                              tried_gradient, trial, alpha, E_trial, g_trial)
    return _Iteration(False, shift, gradient=tried_gradient)


def _diag(H):
    first = H.indptr[:-1]
    if not np.array_equal(H.indices[first], np.arange(H.shape[0])):
        raise ValueError("expected a lower-triangle CSC matrix with sorted indices and a "
                         "stored diagonal")
    return H.data[first]


def _scale(H, D) -> float:
    return float(np.mean(np.abs(_diag(H)) / D)) or 1.0


def _solve_shifted(H, g, D, rel: float, linear: LinearSolver):
    """Solve ``(H + rel * scale * D) p = -g``; None if not positive definite or not descent."""
    # lower-triangle CSC with sorted indices: the diagonal is each column's first entry;
    # adding the shift in place keeps the pattern (and CHOLMOD's analysis) unchanged
    data = H.data.copy()
    data[H.indptr[:-1]] += rel * _scale(H, D) * D
    A = sp.csc_matrix((data, H.indices, H.indptr), shape=H.shape)
    try:
        linear.factorize(A)
    except NotPositiveDefinite:
        return None
    p = -linear.solve(g)
    if not np.all(np.isfinite(p)) or not g @ p < -TOL.exact * np.linalg.norm(g) * np.linalg.norm(p):
        return None
    return p


__all__ = ["LinearSolver", "NotPositiveDefinite", "NewtonResult", "StaticProblem", "newton",
           "HAVE_CHOLMOD", "BACKENDS"]
