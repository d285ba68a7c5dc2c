"""The runners of :data:`pysolver.stages.STAGES`: each calls one stage's function with the
options it takes.

A runner is ``runner(ctx: StageContext) -> dict`` (the stage's summary); the same runner
serves a build (``ctx.build`` is its summary, ``ctx.substage`` runs a step as its own
entry) and the stage's subcommand on a design folder (both None).  The stage functions
keep their own signatures (they are called directly by tests and tools); this module is
the one place where the build's options meet them.
"""

from __future__ import annotations

import functools

from ..design import run_design
from ..refine import refine_design
from ..render import render_design, start_self_check
from ..simulator import (
    contact_if_needed,
    make_report,
    print_verdict,
    simulate_design,
    start_pyvista_probe,
)
from ..temporal import program_design
from . import StageContext


def design(ctx: StageContext) -> dict:
    """The design stage into ``ctx.folder`` (:func:`pysolver.design.run_design`)."""
    return run_design(ctx.source, ctx.folder, progress=ctx.progress, **design_options(ctx))


def design_options(ctx: StageContext) -> dict:
    """The keyword arguments of :func:`pysolver.design.run_design` (``seed``, ``size``,
    ``time_file`` and ``thickness_file`` only when given)."""
    o = ctx.options
    return dict(vertices=o.vertices, time=o.time, scale=o.scale, flattening=o.flattening,
                stencil=o.stencil, params=o.params,
                **o.given("seed", "size"),
                **{k: str(getattr(o, k)) for k in ("time_file", "thickness_file")
                   if getattr(o, k) is not None})


def program(ctx: StageContext) -> dict:
    """Temporal programming (:func:`pysolver.temporal.program_design`)."""
    o = ctx.options
    return program_design(ctx.folder, material=o.material, progress=ctx.progress,
                          fit_landscape=ctx.fit_landscape, robust=o.robust_timing,
                          **o.given("physics"))


def simulate(ctx: StageContext) -> dict:
    """The simulation (:func:`sim.model.simulate.simulate_design`); in a build, again with
    barrier contact when far parts pass through each other (:func:`_contact`)."""
    o = ctx.options
    res = simulate_design(ctx.folder, material=o.material, progress=ctx.progress,
                          solver=o.solver, **_sim_settings(o), **o.given("physics"))
    if ctx.build is not None:
        _contact(ctx, res)
    return res


def _sim_settings(o) -> dict:
    """``t_end``, ``dt`` when given, and ``resume=False`` when asked."""
    return dict(o.given("t_end", "dt"), **({} if o.resume else {"resume": False}))


def _contact(ctx: StageContext, result: dict) -> None:
    """Simulate again with barrier contact (``simulate_contact``, its own entry of the
    build) when the frames just written let far parts pass through each other; later
    stages then simulate with contact too (``ctx.physics``)."""
    physics, hit = contact_if_needed(ctx.folder, ctx.name, ctx.progress)
    if physics is None:
        return
    ctx.physics = physics
    result["contact"] = {"switched_on": True, "collisions": hit}
    o = ctx.options
    ctx.substage("simulate_contact", simulate_design, ctx.folder, material=o.material,
                 progress=ctx.progress, solver=o.solver, physics=physics, **_sim_settings(o))


def refine(ctx: StageContext) -> dict:
    """Rounds of timing correction (:func:`pysolver.refine.refine_design`), each simulated
    with the build's solver and physics; then the contact check again when the build has
    not switched contact on yet (the refined thicknesses may bring far parts together)."""
    o = ctx.options
    hook = functools.partial(simulate_design, solver=o.solver, **o.given("dt"),
                             **({} if ctx.physics is None else {"physics": ctx.physics}))
    res = refine_design(ctx.folder, iterations=o.refine, material=o.material,
                        progress=ctx.progress, simulate=hook, **o.given("t_end"),
                        physics=ctx.physics or o.physics)
    if ctx.build is not None and ctx.physics is None:
        _contact(ctx, res)
    return res


def render(ctx: StageContext) -> dict:
    """The printable parts (:func:`pysolver.render.render_design`)."""
    o = ctx.options
    return render_design(ctx.folder, jobs=o.jobs, progress=ctx.progress, renderer=o.renderer)


def report(ctx: StageContext) -> dict:
    """The simulation check report (:func:`sim.report.make_report`); alone, it also prints
    the verdict (a build prints it when it is complete)."""
    info = None if ctx.build is None else {k: ctx.build[k] for k in ("source", "options",
                                                                    "inputs_sha256")}
    rep = make_report(ctx.folder, progress=ctx.progress, build_info=info)
    if ctx.build is None:
        print_verdict(rep, ctx.folder / "report")
    return rep


def start_render_check(folder, options) -> None:
    """The renderer's self-check, started when a build that renders begins."""
    start_self_check(folder, renderer=options.renderer)


def start_report_probe(folder, options) -> None:
    """The report's off-screen rendering probe (a subprocess), started when a build that
    simulates begins."""
    start_pyvista_probe()


__all__ = ["design", "design_options", "program", "simulate", "refine", "render", "report",
           "start_render_check", "start_report_probe"]
