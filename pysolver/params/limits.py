"""Limits of the options and inputs: a typo is refused at once, not run for hours.

Every bound is named in the message that refuses a value (:class:`~pysolver.errors.InputError`).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Limits:
    """Upper bounds of the size and count options, so that a typo (``--vertices 10000000``)
    is refused at once instead of running for hours.

    Source: morphshell's choices, each far beyond what a real design needs (the paper's
    largest shell has 330 vertices, its simulations 120 s) unless a field says otherwise.

    Attributes
    ----------
    max_vertices : int
        Stencil vertices (``--vertices``); the paper's largest shell has 330.
    max_refine : int
        Timing refinement rounds (``--refine``), each one simulation.
    max_jobs : int
        Parallel render processes (``--jobs``).
    max_t_end : float, s
        Simulated time in water (``--t-end``).
    min_dt : float, s
        Smallest simulation time step (``--dt``).
    max_steps : int
        Simulation steps, ``t_end / dt``.
    max_scale : float
        Input scale factor (``--scale``).
    size_mm : (float, float), mm
        Range of ``--size`` (largest bounding-box extent of the scaled target); the same
        band as the unitless-size check of :mod:`pysolver.design.mesh_input` (bounding-box
        diagonal 20-2000 mm) applied to one extent.
    min_bumper_mm : (float, float), mm
        Range of ``--min-bumper`` (bumper length beyond the base rim, 3D scaling rule).
        Longer than 2 mm, the bumpers would reach past the bracket's roots.
    min_gap_mm : (float, float), mm
        Range of ``--min-gap`` (flat gap between facing bumper tips, 2D scaling rule).
    max_time_file_bytes : int, bytes
        Largest ``--time-file`` or ``--thickness-file`` read (one row per vertex or unit cell:
        millions of them).
    max_cell_length_mm : float, mm
        Upper bound of ``--max-cell-length`` (flat central length of a unit cell): the
        bracket model's last measured length (l = 9.0 mm, ``bracket_length_mm`` grid end
        5.8055 + 3.1945) plus two steps of its 0.25 mm length grid, which is how far the
        clamped model is used today (cells beyond 9.0 mm are warned about).  The lower
        bound is the shortest cell the scaling rules allow, ``2 (base_r + min_bumper) +
        min_gap`` (:meth:`UnitCell.shortest_cell`).
    model_max_central_length_mm : float, mm
        The bracket model's last measured central length (its grid ends at b = 5.8055 mm);
        longer cells (up to ``max_cell_length_mm``) are warned about.
    measured_x_mm, measured_force_N, measured_h_mm : (float, float)
        Plausible peak displacement (mm), peak force (N) and thickness (mm) of a bracket test
        file (:mod:`pysolver.material.measurements`); outside, the column is in another unit.
    measured_duration_s : (float, float), s
        Shortest plausible wet and dry test (they last about 2 min and 7 s).
    render_part_timeout_s : float, s
        A fast-renderer worker stuck this long on one part is killed and the part reported
        failed.
    render_startup_timeout_s : float, s
        Time a new fast-renderer worker may take to import the evaluator before it counts
        as dead.
    probe_timeout_s : float, s
        Time the off-screen rendering probe of the report's pictures may take.
    max_landscape_s : float, s
        Largest time a landscape from the studio may ask for (the material models cover
        about 120 s; the temporal stage clamps or refuses what they cannot reach).
    studio_max_radius_mm : float, mm
        Largest brush radius of the studio (larger than any shell: the whole target).
    studio_max_edits : int
        Most keyframes in one request, and most edits recorded with one run.
    studio_max_body_bytes : int, bytes
        Largest request body the studio reads (a landscape of 5000 vertices is ~60 kB).
    studio_job_timeout_s : float, s
        Longest a studio run (a rebuild) may take before it is stopped.
    studio_max_connections : int
        Connections the studio serves at once, one thread each; more wait in the listen
        queue.  With the body limit, it bounds the threads and the memory requests hold
        (a browser keeps about 6 connections open).
    studio_header_timeout_s : float, s
        Longest the studio waits for a request's line and headers, from the moment it
        starts waiting (on a kept-alive connection: its idle time included); then the
        connection is closed and its slot freed, so slow or idle connections cannot hold
        all ``studio_max_connections`` slots.
    """

    max_vertices: int = 5000
    max_refine: int = 10
    max_jobs: int = 256
    max_t_end: float = 3600.0
    min_dt: float = 0.01
    max_steps: int = 20000
    max_scale: float = 1e6
    size_mm: tuple = (20.0, 2000.0)
    min_bumper_mm: tuple = (0.0, 2.0)
    min_gap_mm: tuple = (0.0, 2.0)
    max_cell_length_mm: float = 9.5
    model_max_central_length_mm: float = 9.0
    measured_x_mm: tuple = (0.05, 100.0)
    measured_force_N: tuple = (0.05, 1000.0)
    measured_h_mm: tuple = (0.05, 5.0)
    measured_duration_s: tuple = (3.0, 1.0)
    max_time_file_bytes: int = 64 * 1024 * 1024
    render_part_timeout_s: float = 300.0
    render_startup_timeout_s: float = 120.0
    probe_timeout_s: float = 120.0
    max_landscape_s: float = 1000.0
    studio_max_radius_mm: float = 1000.0
    studio_max_edits: int = 10000
    studio_max_body_bytes: int = 4 << 20
    studio_job_timeout_s: float = 6 * 3600.0
    studio_max_connections: int = 16
    studio_header_timeout_s: float = 5.0


LIMITS = Limits()


__all__ = ["Limits", "LIMITS"]
