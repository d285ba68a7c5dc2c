"""Unit-cell dimensions, simulation constants and tolerances, in one place.

All lengths mm, forces N, times s, moduli MPa, angles deg unless a name says
``_rad``.  The defaults are the paper's (Supplementary Note 1, 2) and the
reference implementation's (``shared/design/pipeline.md`` §1.1, ``simulator.md``
§1); where they disagree the choice is written next to the field.

The same numbers are the defaults of the OpenSCAD modules in ``scad/``; a test
(``tests/test_scad_modules.py``) checks that the two stay equal.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class UnitCell:
    """Geometry of bases, brackets and bumpers (mm, deg).

    Attributes
    ----------
    base_r : float, mm
        Base disc radius (Ø 4 mm).
    base_th : float, mm
        Layer core thickness; also the side of the square bumper prism.
    base_p : float, mm
        Base indent: extra base height on the membrane side (0.3 mm), which
        leaves a 2 * base_p slot between opposing bumpers for the membrane.
    bracket_w : float, mm
        Bracket height (out of plane), 1 mm.
    min_gap : float, mm
        Minimal flat gap between facing bumper tips (2D scaling rule), 0.1 mm.
        The reference's json has 0.0 (stale); its examples and the paper use 0.1.
    min_bumper : float, mm
        Minimal bumper length beyond the base rim (3D scaling rule).  The paper
        says 0.3 mm, most reference examples 0.1 mm; we follow the paper: a
        longer bumper stops the bracket further from its breaking strain.
    clearance : float, mm
        Printing clearance removed from every bumper tip, 0.05 mm.
    align_r : float, mm
        Alignment hole radius (Ø 1.5 mm; the reference passes 0.75 as radius).
    marker_r, marker_depth : float, mm
        Marker-dot pocket radius and depth on the far face.
    max_cell_length : float, mm
        Longest printable unit cell (flat centre distance), 9.5 mm.
    """

    base_r: float = 2.0
    base_th: float = 2.0
    base_p: float = 0.3
    bracket_w: float = 1.0
    min_gap: float = 0.1
    min_bumper: float = 0.3
    clearance: float = 0.05
    align_r: float = 0.75
    marker_r: float = 0.3
    marker_depth: float = 0.5
    max_cell_length: float = 9.5
    alpha_margin_deg: float = 7.0
    thickness_min: float = 0.30
    thickness_max: float = 0.65

    @property
    def layer_h(self) -> float:
        """Height of one printed layer (base_th + base_p = 2.3 mm)."""
        return self.base_th + self.base_p

    @property
    def alpha_deg(self) -> float:
        """Bracket arm angle to the cell axis: asin(base_th / (2 base_r)) + 7 deg = 37 deg."""
        return math.degrees(math.asin(self.base_th / (2 * self.base_r))) + self.alpha_margin_deg

    @property
    def alpha_rad(self) -> float:
        return math.radians(self.alpha_deg)

    @property
    def bracket_offset(self) -> float:
        """l - b: central length minus bracket length, 2 base_r cos(alpha) = 3.1945 mm."""
        return 2 * self.base_r * math.cos(self.alpha_rad)

    def bracket_length(self, central_length):
        """Bracket length b (mm) of a cell of flat central length l (mm): b = l - 2 r cos(alpha)."""
        return central_length - self.bracket_offset

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class SimConstants:
    """Physical and numerical constants of the simulator (simulator.md §1, §6, §8).

    Attributes
    ----------
    tau : float
        Membrane equibiaxial pre-stretch factor.
    mu : float, MPa
        Membrane shear modulus (incompressible neo-Hookean).
    membrane_h : float, mm
        Membrane thickness.
    kappa_s : float, N/mm^2
        Shear-resisting (cross pair) stiffness, weighted by the flat diagonal sum.
    kappa_c : float, N/mm
        Bumper contact spring stiffness (E = kappa_c/2 (L - L_c)^2; 2 * 99.9).
    eta : float
        Plastic fraction.
    dt, t_end : float, s
        Time step and end time.
    boundary_weakening : float
        Factor on the target membrane force of boundary cells (thickness design).
    """

    tau: float = 3.0
    mu: float = 0.72
    membrane_h: float = 0.5
    kappa_s: float = 0.1
    kappa_c: float = 199.8
    eta: float = 0.2
    dt: float = 0.5
    t_end: float = 120.0
    boundary_weakening: float = 0.6
    membrane_max_area: float = 5.0
    membrane_min_angle: float = 20.0


@dataclass(frozen=True)
class Tolerances:
    """Every geometric and solver tolerance, named (trimesh's ``tol`` habit).

    Attributes
    ----------
    merge : float, mm
        Distance under which two points are the same point.
    stl_bbox : float, mm
        Allowed bounding-box difference between an STL and its table.
    newton_grad : float, N
        Newton convergence: infinity norm of the reduced gradient (forces in N,
        torques in N mm scaled by 1/base_r so both are forces).
    newton_max_iter_dry, newton_max_iter_wet : int
        Newton iteration caps for the dry step and the wet steps.
    """

    merge: float = 1e-6
    stl_bbox: float = 0.05
    newton_grad: float = 1e-6
    newton_max_iter_dry: int = 200
    newton_max_iter_wet: int = 100
    line_search_halvings: int = 30


@dataclass(frozen=True)
class Limits:
    """Upper bounds of the size and count options, so that a typo (``--vertices 10000000``)
    is refused at once instead of running for hours.

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
    """

    max_vertices: int = 5000
    max_refine: int = 10
    max_jobs: int = 256
    max_t_end: float = 3600.0
    min_dt: float = 0.01
    max_steps: int = 20000
    max_scale: float = 1e6


LIMITS = Limits()

DEFAULT_REFINE = 1
"""Rounds of timing refinement from the simulation, the one default of ``morphshell build``,
``make`` and :func:`pysolver.build.build`."""

@dataclass(frozen=True)
class ModelFileRules:
    """Rules of the model-file validator (:mod:`pysolver.material.validate`).

    The bracket (material) model and the membrane model are read from JSON files that a user
    can write or edit; every rule below is checked before any stage runs.

    Attributes
    ----------
    max_bytes : int, bytes
        Largest model file read (the committed bracket model is ~0.3 MB).
    format_version : int
        Newest bracket-model ``format_version`` this code reads.
    grid_min_nodes : int
        Nodes per grid axis at least (trilinear interpolation needs a cell).
    stiffness_min : float, N/mm
        The stiffness at zero compression, ``c1 = F'(0)``, must exceed this at every node.
    stiffness_tol : float, N/mm
        Negative ``F'(x)`` allowed on ``[0, b]`` at a node (round-off of the fit's
        constraints; the committed model reaches -8e-9 N/mm).
    compressions : int
        Compressions ``x = b/n, 2b/n, .., b`` checked at each grid node.
    force_rise_tol : float
        Forces must fall with time in water: at every node and compression, ``F(t)`` may rise
        above its minimum over earlier times by at most this fraction of ``F(t=0)`` (the
        committed model rises by up to 4.9 %, a fit without one specimen by 5.5 %, both at
        b = 0.81 mm, below the measured lengths).
    softening_median_max : float
        The brackets must soften in water: the median over nodes and compressions of
        ``F(t_last) / F(t=0)`` must not exceed this (committed model: 0.056).
    plastic_fraction_max : float
        Upper bound (exclusive) of a stored plastic fraction ``eta`` (lower bound 0).
    membrane_b_range_mm : (float, float), mm
        Flat bracket lengths at which the membrane force is checked (the bracket model's grid
        starts at 0.81 mm; the longest cell, 9.5 mm, has b = 6.31 mm).
    membrane_d_fraction : float
        Shortenings ``d`` in ``[0, membrane_d_fraction * b]`` are checked: the membrane force
        must stay positive and must not grow as the cell shortens (the pre-stretch relaxes).
    membrane_samples : int
        Samples per axis of that check.
    boundary_factor_range : (float, float)
        Allowed ``boundary_factor`` (exclusive lower, inclusive upper bound).
    """

    max_bytes: int = 64 * 1024 * 1024
    format_version: int = 1
    grid_min_nodes: int = 2
    stiffness_min: float = 0.0
    stiffness_tol: float = 1e-6
    compressions: int = 20
    force_rise_tol: float = 0.10
    softening_median_max: float = 0.5
    plastic_fraction_max: float = 1.0
    membrane_b_range_mm: tuple = (0.8, 6.4)
    membrane_d_fraction: float = 0.7
    membrane_samples: int = 12
    boundary_factor_range: tuple = (0.0, 1.0)


@dataclass(frozen=True)
class PhysicsOptions:
    """Physics beyond the reference simulator (issue #18), each switchable, all off by default.

    With every switch off the simulation is the reference model, bit for bit.  Units: mm, N,
    s, MPa; densities in g/cm^3 (= 1e-9 t/mm^3; weights are ``rho * 1e-9 * V * g`` in N
    for ``V`` in mm^3 and ``g`` in mm/s^2).  What each effect does and what it changed on
    the built-in shapes: ``docs/physics.md``.

    Attributes
    ----------
    relaxation : bool
        Membrane stress relaxation (SI Note 5 step 2, SI Fig. 10): the membrane modulus is
        scaled by the measured relaxation function ``g(t)`` (:data:`RELAXATION_PRONY`) of the
        time since stretching, ``stretch_to_glue_min + glue_to_water_min`` plus the time in
        water.
    stretch_to_glue_min : float, min
        Stretching the sheet to gluing the lattices (SI Note 5 steps 2-5; assumed).
    glue_to_water_min : float, min
        Gluing to immersion (steps 6-8: 5 min wait, release, cutting out; assumed).
    gravity : bool
        Weight and buoyancy in water; the shell rests on the tank floor (a plane).
    dry_rest : bool
        After the morph, the dry resting shape on a table: brackets frozen at their final
        lengths with their dry stiffness, full weight, contact with the plane.
    print_density : float, g/cm^3
        Printed parts (Stratasys J750 photopolymers are 1.15-1.20; VeroClear 1.18).
    water_density : float, g/cm^3
        Water at 56 C.
    latex_density : float, g/cm^3
        Natural-rubber latex sheet.
    gravity_mm_s2 : float, mm/s^2
    face_down : {"bottom", "top"}
        The layer that faces the floor and the table (the flat shell lies on it).
    ground_stiffness : float, N/mm^3
        Cubic penalty of the plane contact ``E = k/3 max(0, -d)^3`` (d = height above the
        plane); 1e3 N/mm^3 lets a 1 mN point load sink by 1e-3 mm.
    ground_points : int
        Contact points per base face: the rim of each far face (radius ``base_r``).
    rim : bool
        The membrane as fabricated at the rim (SI Note 5 step 7): a strip of latex
        ``rim_margin_mm`` wide around the outline, cut from the sheet after its release to
        ``rim_stretch`` (instead of the free edge of the reference).
    rim_margin_mm : float, mm
        Width of the latex margin kept at the border (flat, as cut).
    rim_stretch : float
        Pre-stretch of the margin after the release ("near 2").
    contact : bool
        Barrier contact between bases that are not neighbours (IPC Toolkit, ``ipctk``):
        every base a closed prism; no two non-neighbouring prisms pass through each other.
    contact_dhat_mm : float, mm
        Distance below which the barrier acts (below the 0.6 mm that bumpers keep between
        neighbours).
    contact_stiffness : float, N/mm
        Barrier stiffness kappa (energy ``kappa * -(d - dhat)^2 ln(d / dhat)``; 10 N/mm gives
        ~1 N at a tenth of dhat, the scale of the membrane's pull on a cell).
    contact_sides : int
        Sides of the prism that stands for a base disc.
    bracket_bending : bool
        Out-of-plane bending of the brackets (the 1 mm x h section): a rotational spring on
        the relative tilt of the two bases of every cell, its stiffness estimated from the
        brackets' current in-plane stiffness (``sim.physics.bending_stiffness``).
    """

    relaxation: bool = False
    stretch_to_glue_min: float = 10.0
    glue_to_water_min: float = 10.0
    gravity: bool = False
    dry_rest: bool = False
    print_density: float = 1.18
    water_density: float = 0.985
    latex_density: float = 0.93
    gravity_mm_s2: float = 9810.0
    face_down: str = "bottom"
    ground_stiffness: float = 1e3
    ground_points: int = 8
    rim: bool = False
    rim_margin_mm: float = 1.0
    rim_stretch: float = 2.0
    contact: bool = False
    contact_dhat_mm: float = 0.1
    contact_stiffness: float = 10.0
    contact_sides: int = 8
    bracket_bending: bool = False

    SWITCHES = ("relaxation", "gravity", "dry_rest", "rim", "contact", "bracket_bending")

    @property
    def any(self) -> bool:
        """Any effect switched on."""
        return any(getattr(self, k) for k in self.SWITCHES)

    def switched_on(self) -> list:
        return [k for k in self.SWITCHES if getattr(self, k)]

    def to_dict(self) -> dict:
        return asdict(self)


RELAXATION_PRONY = (
    (1.0e1, 3.16227766e1, 1.0e2, 3.16227766e2, 1.0e3, 3.16227766e3, 1.0e4, 3.16227766e4, 1.0e5),
    (0.80176665, 0.02033809, 0.00262854, 0.02778007, 0.02581137, 0.05390961, 0.02105795, 0.0,
     0.01616499, 0.03054273),
)
"""Membrane stress relaxation at stretch 3 (SI Fig. 10,
``data/material-measurements/rubber_stress_relaxation.csv``), normalised Prony series
``g(t) = g_inf + sum_i g_i exp(-t / tau_i)``, ``g(0) = 1``: ``(tau_i (s), (g_inf, g_i...))``.
Fitted by :func:`pysolver.material.relaxation.fit_relaxation` (NNLS, relaxation times fixed at
half decades, samples weighted by ``1/sqrt(t)``); a test refits it from the CSV."""


UNIT_CELL = UnitCell()
SIM = SimConstants()
PHYSICS_OFF = PhysicsOptions()
tol = Tolerances()
MODEL_FILES = ModelFileRules()

LAYERS = ("top", "bottom")
"""Layer names.  ``top`` = +z in the flat print frame = +face-normal side of the
target (the reference's ``o``); ``bottom`` = -z = -normal side (``u``)."""


def layer_sign(layer) -> int:
    """+1 for the top layer (index 0 / ``"top"``), -1 for the bottom layer (1 / ``"bottom"``)."""
    if layer in (0, "top"):
        return 1
    if layer in (1, "bottom"):
        return -1
    raise ValueError(f"layer must be 0/'top' or 1/'bottom', got {layer!r}")


__all__ = ["DEFAULT_REFINE", "LIMITS", "Limits", "UnitCell", "SimConstants", "Tolerances",
           "PhysicsOptions", "PHYSICS_OFF", "RELAXATION_PRONY",
           "ModelFileRules", "UNIT_CELL", "SIM", "tol", "MODEL_FILES", "LAYERS", "layer_sign"]
