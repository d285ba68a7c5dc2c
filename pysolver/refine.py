"""Closing the timing loop: temporal programming <-> simulation (the refine stage).

:func:`refine_design` corrects the programmed times of a programmed and simulated design
folder from the simulated completion times, programs the thicknesses again and simulates
again, for a few rounds, and keeps the best round.  It composes the temporal stage
(:func:`pysolver.temporal.program_cells`) and the simulator (through
:mod:`pysolver.simulator`), which is why it lives here, beside the orchestrator, and not in
either stage.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np

from . import tables
from .core.inputs import read_input
from .core.progress import say
from .core.records import json_text
from .core.writes import atomic_write_text
from .errors import InputError
from .params import PROGRAMMING, REPORT, SIM, UNCERTAINTY, UNIT_CELL
from .simulator import (
    completion_times,
    never_due,
    open_layers,
    read_completion_frames,
    simulate_design,
)
from .temporal import (
    PREDICTED_SD,
    REFINE_LOG,
    STAGE_FILE,
    closing_lengths,
    load_material,
    program_cells,
    sd_list,
    time_limit,
    timing_errors,
    timing_sd,
)
from .temporal.membrane_model import load_membrane_model

NOTE = ("rms_s: cells whose t* is achievable (clamped excluded) and that complete; "
        "rms_incl_never_s also counts cells that never complete as finishing at the last "
        "simulated time; n_never_due: cells due by the last simulated time that never "
        "complete, clamped ones included. The best round has the fewest n_never_due, then "
        "the lowest rms_incl_never_s: a round that closes more cells is kept even at a larger "
        "timing error.")
"""The explanation written with the history (``sim/refine.json``)."""


def refine_design(design_dir, *, iterations: int = 1, material=None, membrane=None,
                  progress: bool = True, t_end=None, damping: float = PROGRAMMING.refine_damping,
                  tol_mm: float = UNIT_CELL.clearance, simulate=None, physics=None) -> dict:
    """Correct the programmed times from simulated completion times and re-simulate.

    Needs a programmed and simulated design folder (``sim/frames.npz``).  Each
    iteration moves the requested time of every cell by ``damping * (t* - t_sim)``
    (cells that never complete count as ``t_end``), clamps it to the cell's
    achievable range, re-solves the thicknesses (``t_star_s`` stays the user's
    target), and re-simulates.  A cell that never completes also has the layers it left
    open thinned (:func:`_thin_open_layers`).  When the ``iterations`` rounds leave cells
    that never complete, up to ``PROGRAMMING.refine_extra_rounds`` more rounds run while
    they do.  The round with the fewest cells that never complete, then the lowest RMS
    timing error (clamped cells excluded, cells that never complete counted as finishing
    at the last frame) is kept: its thicknesses in ``cells.csv`` and its frames in
    ``sim/frames.npz``.

    Parameters
    ----------
    design_dir : path-like
    iterations : int
        Number of correct + re-simulate rounds K (0 = none, and no extra rounds).
    material, membrane : optional
        As :func:`pysolver.temporal.program_design`; ``material`` is also passed to the
        simulator.
    t_end : float, s, optional
        Simulated time (default: the simulator's default).
    damping : float
        Fraction of the timing error corrected per round (0 < damping <= 1).
    tol_mm : float, mm
        Completion tolerance (:func:`sim.model.collisions.completion_times`).
    simulate : callable, optional
        ``simulate(design_dir, **kw)`` replacing :func:`sim.model.simulate.simulate_design`
        (tests; the build passes its solver and physics).
    physics : PhysicsOptions, optional
        The simulator's physics (default :data:`~pysolver.params.PHYSICS_DEFAULT`): the
        layers are programmed to close where it closes them
        (:func:`pysolver.temporal.program.closing_lengths`).

    Returns
    -------
    dict
        ``iterations`` (asked), ``rounds`` (run), ``damping``, ``history`` (per round:
        :func:`timing_errors`, ``n_never_due`` and ``never_due_cells``, the thickness range,
        ``n_layers_thinned``: layers newly capped, and the seconds taken), ``best`` (round
        index, 0 = before refinement: the fewest cells that never complete although due,
        then the lowest ``rms_incl_never_s``), ``before``/``after`` (round 0 and the best
        one) and a ``note``.
    """
    design_dir = Path(design_dir)
    if int(iterations) != iterations or iterations < 0:
        raise InputError(f"iterations must be a non-negative integer, got {iterations!r}.")
    if not 0 < damping <= 1:
        raise InputError(f"damping must be in (0, 1], got {damping!r}.")
    frames_path = design_dir / "sim" / "frames.npz"
    if not frames_path.is_file():
        raise InputError(f"{frames_path} does not exist: refine needs a simulated design.",
                         fix="run the simulate stage first (morphshell simulate DIR).")
    sim_kw = {"progress": progress}
    sim_kw.update({k: v for k, v in (("material", material), ("t_end", t_end)) if v is not None})
    rounds = _Rounds(design_dir, load_material(material), load_membrane_model(membrane),
                     damping=damping, tol_mm=tol_mm, progress=progress, physics=physics)
    k = 0
    while _refine_again(rounds.hist, k, int(iterations)):
        k += 1
        rounds.run(k, int(iterations), simulate or simulate_design, sim_kw)
    best = rounds.keep_best()
    result = {"iterations": int(iterations), "rounds": k, "damping": damping,
              "history": rounds.hist, "best": best, "before": rounds.hist[0],
              "after": rounds.hist[best], "note": NOTE,
              PREDICTED_SD: sd_list(rounds.predicted_sd(rounds.thick[best]))}
    atomic_write_text(design_dir / "sim" / REFINE_LOG,
                      json_text(result, indent=1, sort_keys=False))
    return result


def program_record(folder) -> dict:
    """The program stage's record (``temporal.json``) of the design folder ``folder`` as a
    dict; ``{}`` when the stage wrote none (a folder programmed elsewhere).

    Raises
    ------
    InputError
        The file is there but unreadable, not JSON or not a JSON object.
    """
    path = Path(folder) / STAGE_FILE
    if not path.is_file():
        return {}
    data = read_input(path, "program record")   # InputError: unreadable
    try:
        rec = json.loads(data)
    except ValueError:   # not UTF-8 or not JSON
        rec = None
    if not isinstance(rec, dict):
        raise InputError(f"{path} is damaged (not a JSON object)",
                         fix="run the program stage again: morphshell program "
                             f"{Path(folder)}")
    return rec


class _Rounds:
    """The state of one refinement: the cells, the rounds so far and their thicknesses.

    Round 0 is the simulation the design came with; :meth:`run` adds one, :meth:`keep_best`
    writes the best one back (its thicknesses and frames).
    """

    def __init__(self, folder: Path, mat, mem, *, damping: float, tol_mm: float,
                 progress: bool, physics=None):
        self.folder, self.mat, self.mem = folder, mat, mem
        self.damping, self.tol_mm, self.progress = damping, tol_mm, progress
        self.frames_path = folder / "sim" / "frames.npz"
        self.keep_dir = folder / "sim" / "refine"
        self.cells = tables.read_table(folder, "cells")
        c = self.cells
        self.closing = closing_lengths(folder, c, physics)  # as the simulator closes them
        self.t_star = c["t_star_s"].copy()
        record = program_record(folder)   # (read once: both settings come from it)
        self.factor = self._membrane_factor(record, len(self.t_star))
        self.robust = self._robust(record)
        self.clamped = c["clamped"].astype(bool)
        self.lo = np.where(np.isfinite(c["t_min_s"]), c["t_min_s"], 0.0)
        self.hi = np.where(np.isfinite(c["t_max_s"]), c["t_max_s"], time_limit(mat))
        self.t_sim, t = self._simulated()
        # the correction and the counts of every round measure against round 0's end
        self.t_last = float(t[-1]) if len(t) else float(SIM.t_end)
        self.keep_dir.mkdir(parents=True, exist_ok=True)
        shutil.copy2(self.frames_path, self.keep_dir / "frames_0.npz")
        th0 = np.column_stack([c["thickness_top_mm"], c["thickness_bottom_mm"]])
        self.hist = [_round_record(self.t_star, self.t_sim, self.clamped, self.t_last,
                                   iteration=0,
                                   thickness_mm=[float(th0.min()), float(th0.max())])]
        self.thick = [th0]
        self.cap = np.full(th0.shape, np.inf)
        self.t_req = np.clip(self.t_star, self.lo, np.maximum(self.lo, self.hi))
        h = self.hist[0]
        say("refine", folder.name, f"before refinement rms {h['rms_s']:.2f} s, spearman "
            f"{h['spearman']:.3f}, {h['n_never_due']} never complete", progress)

    @staticmethod
    def _robust(record: dict) -> bool:
        """Whether the program stage programmed the layers against the thickness scatter
        (its ``record``, ``temporal.json`` → ``summary.robust``): the rounds are programmed
        the same way."""
        summary = record.get("summary", {})
        return bool(isinstance(summary, dict) and summary.get("robust", False))

    def _membrane_factor(self, record: dict, n: int):
        """The program stage's per-cell F_mem factor (its ``record``, ``temporal.json``), or
        None."""
        f = record.get("membrane_factor")
        if not isinstance(f, list) or len(f) != n:
            return None
        factor = tables.record_numbers(f, n)
        if factor is None:
            raise InputError(f"{self.folder / STAGE_FILE}: membrane_factor has an entry that "
                             "is not a number", fix="run the program stage again: morphshell "
                                                    f"program {self.folder}")
        return factor

    def _simulated(self):
        """Completion times (s, NaN = never) and frame times (s) of the frames now in the
        folder."""
        frames = read_completion_frames(self.folder)
        return completion_times(frames, tol_mm=self.tol_mm), np.asarray(frames["t"], float)

    def run(self, k: int, asked: int, simulate, sim_kw: dict) -> None:
        """Round ``k``: correct the requested times, program, thin open layers, simulate."""
        t0 = time.perf_counter()
        ts = np.where(np.isfinite(self.t_sim), self.t_sim, self.t_last)
        self.t_req = np.clip(self.t_req + self.damping * (self.t_star - ts), self.lo,
                             np.maximum(self.lo, self.hi))
        c = self.cells
        res = program_cells(c["bracket_length_mm"], self.closing[:, 0], self.closing[:, 1],
                            c["boundary"], self.t_star,
                            material=self.mat, membrane=self.mem, t_request=self.t_req,
                            factor=self.factor, robust=self.robust)
        self.cap, n_thinned = _thin_open_layers(self.cap, self.thick[-1], self.t_sim,
                                                self.t_star, self.t_last, self.frames_path,
                                                self.tol_mm)
        th = np.minimum(res["thickness"], self.cap)
        self.cap = np.where(np.isfinite(self.cap), th, self.cap)  # capped: never thickens
        self._write_thickness(th)
        simulate(self.folder, **sim_kw)
        self.t_sim = self._simulated()[0]
        shutil.copy2(self.frames_path, self.keep_dir / f"frames_{k}.npz")
        self.thick.append(th)
        self.hist.append(_round_record(self.t_star, self.t_sim, self.clamped, self.t_last,
                                       iteration=k,
                                       thickness_mm=[float(th.min()), float(th.max())],
                                       n_layers_thinned=n_thinned,
                                       seconds=round(time.perf_counter() - t0, 1)))
        h = self.hist[-1]
        say("refine", self.folder.name, f"{k}/{max(k, asked)}: rms {h['rms_s']:.2f} s, "
            f"spearman {h['spearman']:.3f}, {h['n_never_due']} never complete "
            f"({h['seconds']:.0f} s)", self.progress, k=k, n=max(k, asked))

    def predicted_sd(self, th):
        """Each cell's completion-time sd (n,) s under the per-bracket thickness scatter for
        the thicknesses ``th`` (n, 2) mm (:func:`pysolver.temporal.program.timing_sd`)."""
        c = self.cells
        res = program_cells(c["bracket_length_mm"], self.closing[:, 0], self.closing[:, 1],
                            c["boundary"], self.t_star, material=self.mat, membrane=self.mem,
                            factor=self.factor, robust=False)
        return timing_sd(self.mat, th, c["bracket_length_mm"], res["x"], res["f_bracket"],
                         UNCERTAINTY.thickness_sd)[0]

    def _write_thickness(self, th) -> None:
        tables.update_cells(self.folder, self.cells, thickness_top_mm=th[:, 0],
                            thickness_bottom_mm=th[:, 1])

    def keep_best(self) -> int:
        """Write the best round's thicknesses and frames back; returns its index."""
        best = _best_iteration(self.hist)
        if best != len(self.hist) - 1:
            self._write_thickness(self.thick[best])
            shutil.copy2(self.keep_dir / f"frames_{best}.npz", self.frames_path)
        for f in self.keep_dir.glob("frames_*.npz"):
            f.unlink()
        self.keep_dir.rmdir()
        return best


def _thin_open_layers(cap, h_prev, t_sim, t_star, t_end, frames_path, tol_mm):
    """Caps on the thickness of the layers that stayed open in a cell that never completed
    although due.

    The time correction cannot close such a cell when it already asks for the cell's
    fastest time (a clamped cell, or a strongly folded one whose one layer must contract
    several times more than the other): the force balance behind the thicknesses
    (:func:`~pysolver.temporal.program.program_cells`) then over-estimates the membrane
    pull the simulation finds.  Each layer the last frame shows open
    (:func:`sim.model.collisions.open_layers`) is capped ``PROGRAMMING.refine_open_layer_mm``
    below its thickness in the round that left it open (not below
    ``UNIT_CELL.thickness_min``).  A capped layer never thickens again in later rounds
    (the caller lowers the cap to the thickness used), so that a cell the cap closed is
    not opened again by the next time correction.

    Parameters
    ----------
    cap : (n, 2) float, mm -- caps so far (``inf`` = none), (top, bottom)
    h_prev : (n, 2) float, mm -- thicknesses of the simulated round
    t_sim, t_star : (n,) float, s -- simulated completion (NaN = never) and targets
    t_end : float, s -- last simulated time
    frames_path : path -- that round's ``frames.npz``
    tol_mm : float, mm -- completion tolerance

    Returns
    -------
    cap : (n, 2) float, mm
    n_thinned : int -- layers newly capped below their previous thickness
    """
    h_prev = np.asarray(h_prev, float)
    thin = open_layers(frames_path, tol_mm) & never_due(t_sim, t_star, t_end)[:, None]
    h_min = UNIT_CELL.thickness_min
    lower = np.maximum(h_min, h_prev - PROGRAMMING.refine_open_layer_mm)
    cap = np.where(thin, np.minimum(cap, lower), cap)
    return cap, int((thin & (h_prev > h_min)).sum())


def _best_iteration(hist) -> int:
    """The refinement round to keep: fewest cells that never complete although due (the
    simulation check's count; clamped cells included), then the lowest
    ``rms_incl_never_s``."""
    def key(h):
        rms = h["rms_incl_never_s"]
        return (h["n_never_due"], rms if np.isfinite(rms) else np.inf)
    return min(range(len(hist)), key=lambda k: key(hist[k]))


def _refine_again(hist, k: int, rounds: int) -> bool:
    """Whether the refinement runs round ``k + 1``: the ``rounds`` asked for, then up to
    ``PROGRAMMING.refine_extra_rounds`` more while the best round so far leaves cells that
    never complete, and the last round either thinned a layer or closed a cell (otherwise
    another simulation could not change anything the time correction has not)."""
    if k < rounds:
        return True
    if rounds == 0 or k >= rounds + PROGRAMMING.refine_extra_rounds:
        return False
    last, before = hist[-1], hist[-2]
    moved = last["n_layers_thinned"] > 0 or last["n_never_due"] < before["n_never_due"]
    return moved and hist[_best_iteration(hist)]["n_never_due"] > 0


def _round_record(t_star, t_sim, clamped, t_end, **extra) -> dict:
    """One refinement round's figures: :func:`timing_errors` and the cells that never
    complete although due (:func:`sim.model.collisions.never_due`)."""
    stuck = never_due(t_sim, t_star, t_end)
    return dict(timing_errors(t_star, t_sim, clamped, t_end), n_never_due=int(stuck.sum()),
                never_due_cells=[int(i) for i in np.flatnonzero(stuck)[:REPORT.listed_cells]],
                **extra)


__all__ = ["refine_design"]
