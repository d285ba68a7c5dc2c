"""The simulator: physical constants, time stepping, the Newton solver, optional physics.

Sources: the reference simulator (``shared/design/simulator.md``, section named per field) and
the paper (SI Notes 2, 5); the solver settings are morphshell's (its Newton iteration is not
the reference's, ``simulator.md`` §8: it uses a line search with Wolfe conditions and an
adaptive regularisation, :mod:`pysolver.mechanics.solver`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class SimConstants:
    """Physical and numerical constants of the simulator.

    Source: the reference simulator's defaults (``simulator.md`` §1, §5, §6), which are the
    paper's (SI Note 2), unless a field says it is morphshell's.

    Attributes
    ----------
    tau : float
        Membrane equibiaxial pre-stretch factor (reference and paper: 3).
    mu : float, MPa
        Membrane shear modulus (incompressible neo-Hookean; reference ``lame2``).
    membrane_h : float, mm
        Membrane thickness (reference ``mem_h``).
    kappa_s : float, N/mm^2
        Shear-resisting (cross pair) stiffness, weighted by the flat diagonal sum (reference
        ``scissor``).
    kappa_c : float, N/mm
        Bumper contact spring stiffness (E = kappa_c/2 (L - L_c)^2; 2 * 99.9, reference
        ``simulator.md`` §5).
    eta : float
        Plastic fraction of the bracket springs in water (reference ``plastic_fraction``).
    dt, t_end : float, s
        Time step and end time (the reference's published examples: 0.5 s, 120 s).
    boundary_weakening : float
        Factor on the target membrane force of boundary cells (thickness design; the
        paper's and the reference's 0.6).
    membrane_max_area : float, mm^2
        Largest flat triangle of the simulator's membrane mesh (reference triangle flags
        ``a5qQ``: area 5 mm^2).
    membrane_min_angle : float, deg
        Smallest angle of that mesh (``q``: Triangle's default 20 deg).
    settle_mm : float, mm
        Early stop of a simulation: every cell in bumper contact in both layers and no base
        centre or vertex moved more than this in a step (``SimSettings.settle_mm``;
        morphshell's, the reference always runs to ``t_end``).
    blowup : float
        Divergence: a step whose total energy exceeds this many times the dry equilibrium
        energy stops the simulation (``SimSettings.blowup``; morphshell's).
    checkpoint_every : int
        A running simulation saves a checkpoint every this many steps, from which an
        interrupted run resumes (0 = never; ``SimSettings.checkpoint_every``).
    contact_skin_mm : float, mm
        Verlet skin of the contact broad phase (``sim.model.contact``): the list of
        non-neighbouring base pairs is built ``2 skin`` wider than needed and reused until
        some base centre has moved ``skin`` from where it was built.
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
    settle_mm: float = 1e-4
    blowup: float = 100.0
    checkpoint_every: int = 20
    contact_skin_mm: float = 1.0


@dataclass(frozen=True)
class NewtonSettings:
    """Settings of the Newton solver (:func:`pysolver.mechanics.solver.newton`) and of the
    line searches that share its constants.

    Source: morphshell's (its solver is not the reference's, ``simulator.md`` §8).  The
    constants of the line search are Nocedal & Wright's usual ones; the iteration caps and
    step limits are morphshell's choices.

    Attributes
    ----------
    max_iter_dry, max_iter_wet : int
        Newton iteration caps of the dry step (from the flat state, many iterations) and of
        each wet step (reference: 1000 and 500, with its plain backtracking).
    max_iter_rest : int
        Cap of the dry resting shape's solve (``--physics dry-rest``): the shell settles
        on a frictionless table by a slow, nearly rigid roll (330 iterations on the
        printed spiral).
    max_rot_rad : float, rad
        Largest rotation of a base per Newton iteration.
    max_step_mm : float, mm
        Largest move of a base centre or membrane vertex per Newton iteration.
    line_search_halvings : int
        Most step halvings of a line search before the next regularisation is tried.
    armijo_c1 : float
        Sufficient-decrease constant of the line searches (Nocedal & Wright's ``c1``; also
        the CETM flattening's).
    wolfe_c2 : float
        Curvature constant of the strong Wolfe line search (Nocedal & Wright's ``c2``).
    shift_min, shift_floor : float
        Smallest regularisation shift of a Newton solve (relative to the mean scaled Hessian
        diagonal), and the floor of the shift a Newton iteration starts from.
    shift_max : float
        Largest adaptive regularisation shift of a Newton solve (relative, as
        ``shift_min``) before the convexified Hessian is tried.
    psd_shifts : tuple of float
        Shifts tried, after ``shift_min``, with the convexified (positive semi-definite)
        Hessian of a Newton solve.
    ccd_safety : float
        Fraction of the collision-free step (continuous collision detection) a Newton step
        may take with contact barriers on (IPC's 0.8).
    """

    max_iter_dry: int = 200
    max_iter_wet: int = 100
    max_iter_rest: int = 1000
    max_rot_rad: float = 0.3
    max_step_mm: float = 2.0
    line_search_halvings: int = 30
    armijo_c1: float = 1e-4
    wolfe_c2: float = 0.9
    shift_min: float = 1e-8
    shift_floor: float = 1e-6
    shift_max: float = 1.0
    psd_shifts: tuple = (1e-4, 1e-2, 1.0)
    ccd_safety: float = 0.8

    @property
    def psd_ladder(self) -> tuple:
        """``shift_min`` then ``psd_shifts``: every shift tried with the convexified Hessian."""
        return (self.shift_min, *self.psd_shifts)


@dataclass(frozen=True)
class PhysicsOptions:
    """Physics beyond the reference simulator (issues #18, #32), each switchable.

    Source: the paper's fabrication notes (SI Note 5) and measurements (SI Fig. 10) where a
    field says so; the material densities are the manufacturers' figures; the contact and
    ground stiffnesses are morphshell's choices (their scale is given with each).

    With every switch off (:data:`PHYSICS_OFF`, ``--physics none``) the simulation is the
    reference model, bit for bit.  The simulator's default is :data:`PHYSICS_DEFAULT`, the
    set chosen against the 3D scan of a printed shell (``docs/physics.md``, "Calibration on a
    printed shell").  Units: mm, N, s, MPa, deg C; densities in g/cm^3 (= 1e-9 t/mm^3;
    weights are ``rho * 1e-9 * V * g`` in N for ``V`` in mm^3 and ``g`` in mm/s^2).  What
    each effect does and what it changes: ``docs/physics.md``.

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
        After the morph, the dry resting shape on a table: the brackets cool under the load
        they carry (each keeps its final force, further deformation meets the dry
        stiffness), the membrane is back at ``lab_temp_c``, full weight, contact with the
        plane.
    drying_min : float, min
        Time from taking the shell out of the water to the scan of the dry shell (SI Note 5
        step 9: "roughly 15 minutes"); only the membrane's relaxation uses it.
    print_density : float, g/cm^3
        Printed parts (Stratasys J750 photopolymers are 1.15-1.20; VeroClear 1.18).
    water_density : float, g/cm^3
        Water at 56 C.
    latex_density : float, g/cm^3
        Natural-rubber latex sheet.
    gravity_mm_s2 : float, mm/s^2
        Standard gravity.
    face_down : {"bottom", "top"}
        The layer that faces the floor and the table (the flat shell lies on it).
    ground_stiffness : float, N/mm^3
        Cubic penalty of the plane contact ``E = k/3 max(0, -d)^3`` (d = height above the
        plane); 1e3 N/mm^3 lets a 1 mN point load sink by 1e-3 mm.
    ground_points : int
        Contact points per base face: the rim of each far face (radius ``base_r``).
    rim : bool
        The membrane as fabricated at the rim (SI Note 5 steps 6-7): a strip of latex
        ``rim_margin_mm`` wide around the outline, the "tiny amount of degenerated latex"
        kept when the shell is cut out.  Glue was spread on it before the sheet was released
        ("to freeze it"), so it keeps the flat shape it had when the glue set: it rests at
        the flat layout divided by ``rim_stretch`` (1 = frozen, no pre-stress) and holds
        the latex of a sheet stretched by ``tau`` (thickness ``membrane_h / tau^2``).
    rim_margin_mm : float, mm
        Width of the latex margin kept at the border (flat, as cut).
    rim_stretch : float
        Pre-stretch the margin keeps after the glue froze it (1: none; ``tau``: the sheet's,
        i.e. unglued latex).  The SI's "stretch factor near 2" is the sheet released
        *after* the margin was frozen, so it does not apply to the margin.
    clearance : bool
        The printed bumpers are ``UnitCell.clearance`` (0.05 mm) short at every tip
        (``scad/bumper.scad``; the reference's printing gap), so a cell closes that much
        further than the target: each bracket spring's contact length is its target
        length minus ``clearance / |n_xy|`` for each of its two bumpers (``n_xy`` = the
        in-plane part of the bumper's end-plane normal, as in
        :func:`pysolver.design.layout.footprint_rectangles` with ``printed=True``).
    membrane_temperature : bool
        Rubber elasticity is entropic: at a fixed stretch the latex's stress is
        proportional to the absolute temperature.  In the water the membrane modulus is
        ``mu * (water_temp_c + 273.15) / (lab_temp_c + 273.15)`` (x 1.115 for 56 and 22
        deg C); the dry rest is back at ``lab_temp_c``.
    water_temp_c : float, deg C
        Water temperature (SI Note 5 step 8: 56 deg C).
    lab_temp_c : float, deg C
        Room temperature at which the membrane's modulus and relaxation were measured and
        the shell was fabricated and scanned (assumed 22 deg C; 20-25 changes the factor by
        +-0.9 %).
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
    bumper_compliance : bool
        The bumpers of a closed cell are the printed polymer in hot water, not a rigid stop:
        each bracket spring at its bumpers gets half the axial stiffness of its layer's
        bumper pair, ``E(t) A / (2 L)`` (``A = base_th^2``, the bumpers' square section;
        ``L`` = the two bumpers' length beyond the base discs, ``L_c - 2 base_r (1 -
        cos alpha)``, at least ``2 min_bumper``), with ``E(t)`` the polymer's effective
        modulus after ``t`` in the water (:data:`BUMPER_MODULUS`, from the unit-cell creep
        tests) instead of the reference's penalty ``kappa_c``.  The dry rest keeps the
        bumpers' final force and meets the dry modulus.
    bracket_bending : bool
        Out-of-plane bending of the brackets (the 1 mm x h section): a rotational spring on
        the relative tilt of the two bases of every cell, its stiffness estimated from the
        brackets' current in-plane stiffness (``sim.model.physics.bending_stiffness``).
    """

    relaxation: bool = False
    stretch_to_glue_min: float = 10.0
    glue_to_water_min: float = 10.0
    gravity: bool = False
    dry_rest: bool = False
    drying_min: float = 15.0
    print_density: float = 1.18
    water_density: float = 0.985
    latex_density: float = 0.93
    gravity_mm_s2: float = 9810.0
    face_down: str = "bottom"
    ground_stiffness: float = 1e3
    ground_points: int = 8
    rim: bool = False
    rim_margin_mm: float = 1.0
    rim_stretch: float = 1.0
    contact: bool = False
    contact_dhat_mm: float = 0.1
    contact_stiffness: float = 10.0
    contact_sides: int = 8
    bracket_bending: bool = False
    clearance: bool = False
    membrane_temperature: bool = False
    bumper_compliance: bool = False
    water_temp_c: float = 56.0
    lab_temp_c: float = 22.0

    SWITCHES = ("clearance", "bumper_compliance", "relaxation", "membrane_temperature",
                "gravity", "dry_rest", "rim", "contact", "bracket_bending")
    RANGES = {"stretch_to_glue_min": (0.0, 1e5), "glue_to_water_min": (0.0, 1e5),
              "drying_min": (0.0, 1e5), "rim_stretch": (1.0, 10.0),
              "ground_points": (3, 64), "contact_sides": (3, 64),
              "water_temp_c": (0.0, 100.0), "lab_temp_c": (0.0, 100.0)}
    """Accepted ranges (inclusive) of the options that are not simply positive; the
    barrier distance ``contact_dhat_mm`` must also stay below the gap that the bumpers keep
    between neighbouring bases, ``2 UnitCell.min_bumper`` (0.6 mm)."""

    @property
    def any(self) -> bool:
        """Any effect switched on."""
        return any(getattr(self, k) for k in self.SWITCHES)

    def switched_on(self) -> list:
        return [k for k in self.SWITCHES if getattr(self, k)]

    def to_dict(self) -> dict:
        return asdict(self)

    def temperature_factor(self, wet: bool = True) -> float:
        """Factor on the membrane modulus: ``T_water / T_lab`` (absolute temperatures) in
        the water with ``membrane_temperature`` on, else 1."""
        if not (self.membrane_temperature and wet):
            return 1.0
        return (self.water_temp_c + 273.15) / (self.lab_temp_c + 273.15)


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


BUMPER_MODULUS = (
    (5.0, 10.0, 20.0, 30.0, 45.0, 60.0, 90.0, 120.0),
    (379.7, 288.4, 161.0, 78.82, 49.04, 31.70, 21.35, 16.32),
    3095.0,
)
"""The printed polymer's effective modulus in 56 C water, for the bumpers of closed cells
(``PhysicsOptions.bumper_compliance``): ``(t (s) in water, E(t) (MPa), dry E (MPa))``.
Medians over the unit-cell creep tests read through the V-bracket beam model (long cells,
loads of 1-2 N, small deflection), and the dry modulus from the long dry cells;
:mod:`pysolver.material.bumper` derives them and a test recomputes them from the CSVs."""


SIM = SimConstants()
NEWTON = NewtonSettings()
PHYSICS_OFF = PhysicsOptions()
"""Every effect off: the reference simulator's model (``--physics none``)."""
PHYSICS_DEFAULT = PhysicsOptions(clearance=True)
"""The simulator's default physics (``--physics default``), chosen on the printed spiral's
scan (issue #32): the effects that bring the simulation closer to the scan with measured or
fabrication-given parameters.  The table of every option and the reasons are in
``docs/physics.md``."""

__all__ = ["SimConstants", "SIM", "NewtonSettings", "NEWTON", "PhysicsOptions", "PHYSICS_OFF",
           "PHYSICS_DEFAULT", "RELAXATION_PRONY", "BUMPER_MODULUS"]
