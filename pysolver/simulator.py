"""The gateway to the simulator: the one module of ``pysolver`` that imports ``sim``.

Data flows forward (``docs/for-contributors.md``): the design-side packages never see the
simulator, and the front ends (the build and its stage runners, the refinement, the
tolerance analysis, the studio, the command line) reach it, its check and its report only
through the names here.  ``tests/test_architecture.py`` keeps it so.
"""

from __future__ import annotations

from pathlib import Path

from sim.model.collisions import completion_times, never_due, open_layers, read_completion_frames
from sim.model.mechtest import dried_shell, run_test
from sim.model.physics import parse_physics
from sim.model.simulate import SimSettings, simulate_design, simulate_model
from sim.report import base_base_collisions, check_morph, load_sim, make_report, print_verdict
from sim.report.fabrication import parts_made_from, stl_inventory
from sim.report.mechtest import check_targets as check_mechtest_targets  # noqa: F401 (commands)
from sim.report.mechtest import write_mechtest
from sim.report.plots import start_pyvista_probe
from sim.report.scan import compare_scan
from sim.report.verdict import BASE_COLLISION_TEXT
from sim.viewer import ASSETS as VIEWER_ASSETS
from sim.viewer import STATIC_DIR as VIEWER_DIR
from sim.viewer import viewer_data

from .core.progress import say
from .params import MECHTEST, TESTS


def check_sim_span(t_end: float, dt: float) -> None:
    """Refuse a simulated span that the simulator would refuse, before any work is spent.

    Parameters
    ----------
    t_end : float, s
        End of the simulated time.
    dt : float, s
        Time step; ``t_end`` must be a whole number of steps.

    Raises
    ------
    InputError
        Naming the value and the rule.
    """
    SimSettings(t_end=float(t_end), dt=float(dt)).times()


def simulate_and_check(model, material, design, *, t_end: float, dt: float, thresholds=None):
    """Simulate a shell model in memory and judge it with the report's one check
    (:func:`sim.report.verdict.check_morph`).

    Parameters
    ----------
    model : pysolver.mechanics.ShellModel
        The shell (e.g. a perturbed copy from :func:`pysolver.mechanics.vary_model`).
    material : BracketModel
        Anything with the bracket model's ``coefficients``.
    design : pysolver.tables.Design
        The design the model was made from (targets, t*, its own unit cell).
    t_end, dt : float, s
        Simulated span and time step.
    thresholds : ReportThresholds or dict, optional
        Verdict limits (default: the report's).

    Returns
    -------
    frames : dict
        As :func:`sim.model.simulate.simulate_model` returns them.
    check : sim.report.Check or None
        None with fewer than two frames.

    Raises
    ------
    MorphshellError
        When the simulation diverges (raised by the simulator, before any check).
    """
    frames = simulate_model(model, material, t_end=t_end, dt=dt)
    if len(frames["t"]) < 2:
        return frames, None
    return frames, check_morph(frames, design, thresholds)


def contact_if_needed(folder: Path, name: str, progress: bool):
    """Physics options with barrier contact when the simulation of ``folder`` lets
    non-neighbouring bases pass through each other.

    The reference model has no contact between far-apart parts; when they meet on the way
    (a petal sweeping past another), its path is impossible and the check could only say
    FAIL.  The printed shell's parts push each other aside instead, which the IPC barrier
    (``--physics contact``, :mod:`sim.model.contact`) models, so the build simulates again
    with it (on top of the default physics).  A shell whose parts never meet keeps its
    first result unchanged.

    Returns
    -------
    physics : PhysicsOptions or None
        The default physics with ``contact`` switched on; None when no pair collides.
    hit : dict
        :meth:`sim.model.collisions.CollisionResult.summary` of the frames checked.
    """
    hit = base_base_collisions(folder)
    if not hit["count"]:
        return None, hit
    f = hit["first"]
    say("build", name, f"{hit['count']} pair(s) of non-neighbouring bases pass through each "
        f"other (first bases {f['pair'][0]} and {f['pair'][1]} at t = {f['time_s']:g} s); "
        "simulating again with barrier contact (--physics contact)", progress)
    return parse_physics("default,contact"), hit


def viewer_assets() -> dict:
    """The 3D morph viewer's static files, ``{name: path}`` (the studio serves them)."""
    return {name: VIEWER_DIR / name for name in VIEWER_ASSETS}


def morph_viewer(folder, *, max_frames: int, quantise: bool) -> dict:
    """The 3D viewer's data of a simulated design folder (:func:`sim.viewer.viewer_data`).

    Parameters
    ----------
    folder : path-like
        Design folder with ``sim/frames.npz``.
    max_frames : int
        Frames kept (evenly spaced, the end kept).
    quantise : bool
        Positions as uint16 over their box (smaller) rather than float32.

    Returns
    -------
    dict
        The JSON the viewer reads.
    """
    sd = load_sim(folder)
    return viewer_data(sd, completion_times(sd.frames), max_frames=max_frames,
                       quantise=quantise)


def build_parts(folder) -> dict:
    """The printable parts of a build: whether they match its tables
    (:func:`sim.report.fabrication.parts_made_from`) and, when they do, the STL list
    (:func:`sim.report.fabrication.stl_inventory`: name, bytes, triangles, size, purpose).

    Returns
    -------
    dict
        ``made_from`` and ``stls`` (empty when the STLs are stale or absent).
    """
    made = parts_made_from(folder)
    return {"made_from": made, "stls": stl_inventory(folder, made)}


def mechtest(folder, tests=TESTS, *, axis_deg: float = 90.0, material=None,
             progress: bool = True, consts=MECHTEST) -> dict:
    """``morphshell mechtest``: SI Note 6's tests on the morphed, dried shell of a simulated
    design folder (:mod:`sim.model.mechtest`), written to ``folder/mechtest/``
    (:mod:`sim.report.mechtest`) once every test has run.

    Parameters
    ----------
    folder : path-like -- a simulated design folder
    tests : sequence of str -- of :data:`~pysolver.params.TESTS`
    axis_deg : float, deg -- the load's in-plane direction from the flat x axis
    material : path-like, optional -- bracket model file (default: the committed one)

    Returns
    -------
    dict -- the summary written (``tests``, ``shell``)
    """
    folder = Path(folder)
    label = folder.name
    shell = dried_shell(folder, material, consts)
    say("mechtest", label, f"dried shell: {shell.model.n_bases} bases, "
        f"{int(shell.closed.sum())}/{len(shell.closed)} bracket springs at their bumpers",
        progress)
    curves = {t: run_test(shell, t, axis_deg=axis_deg, consts=consts, progress=progress,
                          label=label) for t in tests}
    record = write_mechtest(folder, curves, shell.info, consts)
    for t in tests:
        r = record["tests"][t]
        say("mechtest", label, f"{t}: initial slope {r['initial_slope']:.4g} "
            f"{r['initial_slope_unit']}, peak {r['peak_stress_MPa']:.4g} MPa at "
            f"{r['peak_at']:.3g} {r['peak_at_unit']} ({r['limit']})", progress)
    say("mechtest", label, f"-> {folder / 'mechtest'}", progress)
    return record


__all__ = ["check_sim_span", "mechtest", "simulate_and_check", "contact_if_needed", "viewer_assets",
           "morph_viewer", "build_parts", "simulate_design", "make_report", "print_verdict",
           "never_due", "open_layers", "completion_times", "read_completion_frames",
           "parse_physics", "start_pyvista_probe", "compare_scan", "BASE_COLLISION_TEXT"]
