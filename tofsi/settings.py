"""Physical and numerical settings of a scene: fluid, structure, design, optimizer.

Each class is one TOML table of a scene file (``[fluid]``, ``[structure]``,
``[design]``, ``[optimizer]``); every field states its unit and range.
"""

from __future__ import annotations

from dataclasses import dataclass

from tofsi.config import option
from tofsi.errors import InputError
from tofsi.mesh import SIDES
from tofsi.registry import OBJECTIVES

MAX_STIFFENING = 1e6
"""Largest stiffening factor of an element layer. Far beyond it a layer is rigid to round-off:
measured on the foil rotated 30 degrees (one stiffened layer), the Yeoh mover's minimum
skewness is 0.585 at a factor 1e3 and 0.562 at 1e6, and its Newton fails from 1e8 on (the
tangent's conditioning grows with the factor); the linear and spring movers change by less
than 0.02 between 1e3 and 1e30."""


@dataclass(frozen=True)
class SideFlow:
    """Openings in one side of the channel (table ``[fluid.<side>]``); the rest of the side is a
    no-slip wall. Positions run along the side: y on the left and right sides, x on the bottom
    and top. Listing any opening in any side replaces the default channel (inflow over the
    whole left side, open right side): every side is then a wall except what is listed."""

    inflow: tuple[tuple[float, ...], ...] = option((), length=3,
                                                   doc="prescribed inflow segments [from, to, peak]: "
                                                       "parabolic velocity into the channel [m, m, m/s]")
    outflow: tuple[tuple[float, ...], ...] = option((), length=3,
                                                    doc="prescribed outflow segments [from, to, peak]: "
                                                        "parabolic velocity out of the channel [m, m, m/s]")
    open: tuple[tuple[float, ...], ...] = option((), length=2,
                                                 doc="open outlet segments [from, to] [m] with the natural "
                                                     "condition of fluid.outlet")
    uniform: tuple[tuple[float, ...], ...] = option((), length=4,
                                                    doc="segments [from, to, vx, vy] where the velocity is "
                                                        "the constant (vx, vy), end points included [m, m, "
                                                        "m/s, m/s]: a free stream or a moving wall (topFlow's "
                                                        "rugby ball)")

    def __post_init__(self):
        for name in ("inflow", "outflow", "open", "uniform"):
            for i, segment in enumerate(getattr(self, name)):
                if not segment[0] < segment[1]:
                    raise InputError(f"{name}[{i}]", list(segment[:2]), "need from < to")

    @property
    def is_empty(self) -> bool:
        return not (self.inflow or self.outflow or self.open or self.uniform)


@dataclass(frozen=True)
class FluidSettings:
    """Steady incompressible flow with Brinkman friction (table ``[fluid]``)."""

    density: float = option(1.0, ge=0, doc="fluid density [kg/m^3]; 0 gives Stokes flow")
    viscosity: float = option(1.0, gt=0, doc="dynamic viscosity [Pa s]")
    inlet_velocity: float = option(1.0, doc="peak of the parabolic inflow over the whole left side "
                                                 "(the default channel) [m/s]")
    inlets: tuple[tuple[float, ...], ...] = option((), length=3,
                                                   doc="inflow segments [y0, y1, peak velocity] on "
                                                       "the left side; empty: the whole side (unless "
                                                       "a fluid.<side> table lists openings)")
    outlets: tuple[tuple[float, ...], ...] = option((), length=3,
                                                    doc="prescribed outflow segments [y0, y1, peak] on "
                                                        "the right side; empty: the side open (unless "
                                                        "a fluid.<side> table lists openings)")
    element: str = option("q2q1", choices=("q2q1", "q1q1"),
                          doc="finite element: q2q1, Taylor-Hood (inf-sup stable, exact for Poiseuille "
                              "flow); q1q1, equal-order bilinear velocity and pressure with topFlow's "
                              "SUPG/PSPG stabilization (the element of topFlow and TOFLUX: a third of "
                              "the unknowns on the same mesh, one order less accurate)")
    outlet: str = option("zero-pressure", choices=("zero-pressure", "traction-free", "fixed-pressure"),
                         doc="outlet condition: zero-pressure, mu dv/dn - p n = 0 (zero pressure for "
                             "developed flow); traction-free, (-p I + 2 mu eps(v)) n = 0; "
                             "fixed-pressure, p = 0 at the open segments' nodes, their end nodes "
                             "included (normal velocity free there), with the strain-rate viscous "
                             "form: topFlow's and TOFLUX's outlets")
    parallel_outflow: bool = option(False, doc="open outlets: tangential velocity 0, the flow leaves "
                                               "along the normal (as topFlow's outlets)")
    left: SideFlow = option(SideFlow(), doc="openings in the left side")
    right: SideFlow = option(SideFlow(), doc="openings in the right side")
    bottom: SideFlow = option(SideFlow(), doc="openings in the bottom side")
    top: SideFlow = option(SideFlow(), doc="openings in the top side")
    alpha_max: float = option(1e5, gt=0, doc="Brinkman friction of solid [kg/(m^3 s)]")
    alpha_min: float = option(0.0, ge=0, doc="Brinkman friction of fluid [kg/(m^3 s)]")
    newton_tol: float = option(1e-10, gt=0, lt=1, doc="Newton tolerance on the residual, "
                               "relative to the residual of the zero state")
    newton_max_iter: int = option(25, ge=1, le=1000, doc="Newton iterations per solve")
    continuation_steps: int = option(4, ge=1, le=100,
                                     doc="Reynolds continuation steps tried when a direct "
                                         "Navier-Stokes solve fails")

    def __post_init__(self):
        if self.alpha_min > self.alpha_max:
            raise InputError("alpha_min", self.alpha_min,
                             f"allowed: 0 <= alpha_min <= alpha_max = {self.alpha_max}")
        for name in ("inlets", "outlets"):
            for i, (y0, y1, _) in enumerate(getattr(self, name)):
                if not y0 < y1:
                    raise InputError(f"{name}[{i}]", [y0, y1], "need y0 < y1")


@dataclass(frozen=True)
class StructureSettings:
    """Plane-strain elasticity with SIMP interpolation, small or finite strain (table ``[structure]``)."""

    youngs_modulus: float = option(1e5, gt=0, doc="Young's modulus of solid E0 [Pa]")
    poisson_ratio: float = option(0.3, gt=-1.0, lt=0.5, doc="Poisson's ratio")
    e_min_ratio: float = option(1e-9, gt=0, lt=1, doc="Emin / E0 of void (fluid) elements")
    clamped: tuple[str, ...] = option(("bottom",), doc="where the structure is clamped (at least one): channel "
                                                       "sides (left, right, bottom, top) and named solids "
                                                       "(geometry.solid_names, geometry.circle_names), whose "
                                                       "every node is held")
    load: str = option("reaction", choices=("reaction", "stress-divergence", "pressure"),
                       doc="the fluid's force on the solid: reaction, the momentum-consistent "
                           "reaction of the fluid residual (its resultant tends to the no-slip "
                           "body's drag and lift); stress-divergence, Lundgaard et al. 2018's "
                           "volume form of the total stress inside the solid (loses the viscous "
                           "shear of an unresolved Brinkman layer; for reproducing published results); "
                           "pressure, the same form with the pressure alone (TOFLUX's load)")
    load_exponent: float = option(1.0, ge=1, le=10,
                                  doc="weight rho^k of the solid phase in the fluid load (1: Lundgaard "
                                      "et al.; the SIMP exponent keeps gray elements' displacement "
                                      "bounded)")
    density: float = option(0.0, ge=0, doc="density of the solid rho_s [kg/m^3]: with structure.gravity its "
                            "weight, a dead load on the solid phase weighted like the fluid load (rho^k)")
    gravity: tuple[float, ...] = option((0.0, 0.0), length=2,
                                        doc="gravitational acceleration [gx, gy] [m/s^2] acting on the solid "
                                            "(e.g. [0, -9.81]); [0, 0]: no weight")
    model: str = option("linear", choices=("linear", "neo-hookean", "saint-venant-kirchhoff"),
                        doc="linear: small-strain elasticity; neo-hookean: compressible neo-Hookean at "
                            "finite strain (plane strain, total Lagrangian), solved by Newton with load "
                            "steps; saint-venant-kirchhoff: the same with W = lam/2 (tr E)^2 + mu E:E in "
                            "the Green-Lagrange strain E (Turek & Hron's solid); at finite strain the "
                            "fluid load acts on the moved configuration")
    interpolation: str = option("energy", choices=("energy", "simp"),
                                doc="finite strain: nearly void elements -- energy: Wang et al. 2014's "
                                    "blend of the nonlinear and the linear strain energy by density "
                                    "(void elements linear, so they cannot invert or stall Newton); "
                                    "simp: every element neo-Hookean")
    energy_threshold: float = option(0.01, gt=0, lt=1,
                                     doc="finite strain, energy: density rho0 where the blend g(rho) turns "
                                         "from linear (below) to nonlinear (above)")
    energy_sharpness: float = option(500.0, gt=0, le=1e4, doc="finite strain, energy: steepness beta of g(rho)")
    newton_tol: float = option(1e-10, gt=0, lt=1, doc="finite strain: Newton tolerance, the norm of S on "
                                                      "the free dofs relative to the load's")
    max_newton: int = option(25, ge=1, le=1000, doc="finite strain: Newton iterations per load step")
    max_cutbacks: int = option(20, ge=0, le=1000, doc="finite strain: halvings of the load step before failing")

    def __post_init__(self):
        if not self.clamped:
            raise InputError("clamped", [], "allowed: at least one of " + ", ".join(map(repr, SIDES))
                             + " (a structure held nowhere has no stiffness against rigid motion)")


@dataclass(frozen=True)
class CoupledSettings:
    """The two-way coupled solve (table ``[coupled]``)."""

    method: str = option("auto", choices=("auto", "partitioned", "monolithic"),
                         doc="fixed point with Aitken relaxation, or Newton on the block Jacobian "
                             "(needs a mover with a residual form); auto: monolithic when the mover "
                             "has a residual form, partitioned otherwise")
    tol: float = option(1e-9, gt=0, lt=1, doc="relative change of u (partitioned) or residual "
                                               "per block (monolithic)")
    max_iter: int = option(60, ge=1, le=10_000, doc="coupling iterations")
    relaxation: float = option(0.5, gt=0, le=1, doc="first Aitken relaxation factor")
    quasi_newton: bool = option(True, doc="monolithic: keep the shape derivatives (F_x, S_x) of the "
                                          "first iterate for the rest of the Newton solve (the "
                                          "adjoint gets the exact ones of the converged state)")
    load_ramp: bool = option(True, doc="when a two-way coupled solve fails at the full inflow from its warm "
                                       "start, ramp the inflow from rest in adaptive steps (each warm-"
                                       "started from the last, halved on failure) to carry it to large "
                                       "motion")
    min_load_step: float = option(1.0 / 64.0, gt=0, le=1, doc="the smallest step of the inflow ramp "
                                  "(fraction of the inflow) before the solve fails")
    linear_solver: str = option("block", choices=("block", "direct"),
                                doc="monolithic: the Newton's linear solver -- block: GMRES preconditioned "
                                    "by block Gauss-Seidel over the fields' own factorizations (flow, "
                                    "structure, mesh); direct: the LU of the whole coupled Jacobian. Both "
                                    "converge to the same solution; block is faster, direct the fallback")


@dataclass(frozen=True)
class DesignSettings:
    """Density design: objective, volume, filter and projection (table ``[design]``)."""

    objective: str = option("compliance", choices=OBJECTIVES.names,
                            doc="quantity to minimize, an entry of the objectives registry "
                                "(tofsi.objectives; their descriptions follow the table)")
    volume_fraction: float = option(0.25, gt=0, lt=1,
                                    doc="upper bound of the constrained phase's fraction of the "
                                        "design region")
    constraint: str = option("solid", choices=("solid", "fluid"),
                             doc="the phase whose fraction volume_fraction bounds (fluid: flow problems)")
    filter_radius: float = option(0.045, gt=0, doc="density filter radius [m]")
    filter_kernel: str = option("linear", choices=("linear", "circular"),
                                doc="filter weights at distance d: linear, r - d (a hat); circular, "
                                    "sqrt(1 - d^2 / r^2) (TOFLUX's)")
    filter_fixed: bool = option(False, doc="the filter also averages the fixed elements within its "
                                           "radius at their values (1 solid, 0 fluid), as TOFLUX: the "
                                           "design next to a fixed solid starts partly solid")
    eta: float = option(0.5, gt=0, lt=1, doc="projection threshold")
    beta: tuple[float, ...] = option((1.0, 2.0, 4.0, 8.0, 16.0), ge=0, le=1000,
                                     doc="projection sharpness schedule (one value per stage)")
    penalty: tuple[float, ...] = option((3.0,), ge=1, le=10,
                                        doc="SIMP exponent p of E = Emin + rho^p (E0 - Emin), one "
                                            "value per stage (last value kept); `tofsi solve` uses "
                                            "the first (alias: structure.simp_penalty)")
    brinkman_q: tuple[float, ...] = option((0.1,), gt=0,
                                           doc="convexity q of the Brinkman interpolation, one value "
                                               "per stage (last value kept); `tofsi solve` uses the "
                                               "first (alias: fluid.brinkman_q)")
    coupling: tuple[str, ...] = option((), choices=("one-way", "two-way"),
                                       doc="coupling of each stage (last value kept) for a two-way "
                                           "scene: one-way stages first find the topology at one-way "
                                           "cost, two-way stages design against the deforming flow; "
                                           "empty: effects.coupling throughout")
    min_skewness: float = option(-1.0, ge=-1, lt=1,
                                 doc="two-way stages: the constraint KS_p(corner skewness of the moved "
                                     "fluid mesh) >= min_skewness (1 square corners, 0 degenerate; -1: "
                                     "no constraint), so the optimizer steers away from designs whose "
                                     "mesh would fold")
    skewness_ks: float = option(100.0, gt=0, le=1e4,
                                doc="KS parameter p of the mesh-quality constraint's soft minimum (within "
                                    "log(4 E)/p below the worst corner)")
    structure_model: tuple[str, ...] = option((), choices=("linear", "neo-hookean", "saint-venant-kirchhoff"),
                                              doc="structure model of each stage (last value kept): "
                                                  "small strain while the design is gray (a gray start is "
                                                  "no physical state either way, and finite strain crushes "
                                                  "it), finite strain once the topology exists; empty: "
                                                  "structure.model throughout")
    stage_iterations: int = option(40, ge=1, doc="optimizer iterations per continuation stage")
    initial: str = option("", doc="design to start from: a design.npy of an earlier run "
                                  "(path relative to the working directory), or a number in [0, 1] "
                                  "(that uniform design, e.g. \"1e-4\" as TOFLUX); empty: uniform at "
                                  "the volume bound")

    def __post_init__(self):
        if not self.beta:
            raise InputError("beta", [], "needs at least one value (the projection sharpness of "
                             "each continuation stage; 0: no projection)")

    @property
    def n_stages(self) -> int:
        """Continuation stages: the longest schedule (the others keep their last value)."""
        return max(len(self.beta), len(self.penalty), len(self.brinkman_q), len(self.coupling),
                   len(self.structure_model), 1)


@dataclass(frozen=True)
class OptimizerSettings:
    """The optimizer (table ``[optimizer]``): NLopt's MMA or CCSAQ, or optimality criteria."""

    algorithm: str = option("MMA", choices=("MMA", "CCSAQ", "OC"),
                            doc="NLopt LD_MMA or LD_CCSAQ, or OC: topFlow's optimality criteria "
                                "(one volume bound; exponent 1/3, move limit optimizer.move_limit)")
    max_iter: int = option(200, ge=1, doc="largest number of design iterations")
    tol_change: float = option(1e-3, gt=0, doc="stop when max |gamma change| falls below")
    tol_objective: float = option(1e-6, gt=0, doc="stop on relative objective change below")
    stall_iterations: int = option(3, ge=1, le=100,
                                   doc="a stage ends when the relative objective change stays below "
                                       "tol_objective this many iterations in a row (topFlow: 5)")
    move_limit: float = option(0.2, gt=0, le=1, doc="largest change of a design variable per OC step")
    output_every: int = option(10, ge=1, doc="write pictures and VTU every N iterations")
    max_failures: int = option(5, ge=1, le=1000,
                               doc="failed trial designs in a row (a coupled solve or mesh motion that "
                                   "fails) before the run stops with exit status 3; after each, MMA "
                                   "restarts from the last good design with half its move limit")


@dataclass(frozen=True)
class SolverSettings:
    """Linear algebra: the sparse direct backend, threads and the memory limit (table ``[solver]``)."""

    linear_solver: str = option("superlu", choices=("auto", "superlu", "pardiso", "petsc", "iterative"),
                                doc="sparse direct backend: superlu (always present, bitwise "
                                    "reproducible), pardiso (MKL, pip extra 'fast'), petsc "
                                    "(MUMPS through petsc4py, distributed under mpiexec), "
                                    "auto (the fastest installed); or iterative (no LU: "
                                    "block-preconditioned FGMRES for the flow, AMG-CG for the "
                                    "structure and the movers; docs/parallel.md)")
    threads: int = option(0, ge=0, le=4096, doc="threads of the sparse direct backend "
                                                "(0: one per core)")
    blas_threads: int = option(1, ge=0, le=4096,
                               doc="OpenBLAS threads of NumPy/SciPy (1: fastest measured here and "
                                   "robust on a shared machine; 0: leave as the environment says)")
    max_memory_gb: float = option(0.0, ge=0, doc="refuse a solve whose estimated memory exceeds "
                                                 "this [GB] (0: the machine's available memory)")


BAND_MODES = ("off", "auto", "layers", "distance")


@dataclass(frozen=True)
class BandSettings:
    """Band-localized mesh motion (table ``[mover.band]``, see :mod:`tofsi.band`)."""

    mode: str = option("off", choices=BAND_MODES,
                       doc="off: the mover moves the whole fluid mesh; layers / distance: only the "
                           "quads within `layers` element layers / `distance` of the structure, the "
                           "band's outer edge held fixed; auto: the distance from the size of the motion")
    layers: int = option(8, ge=1, le=100_000, doc="element layers of the band (mode layers); the "
                                                   "least the band holds in mode auto")
    distance: float = option(0.1, gt=0, doc="reach of the band from the structure [m] (mode distance)")
    motion_multiple: float = option(15.0, gt=0, doc="mode auto: the band reaches this multiple of the "
                                                   "structure's largest displacement (when known: "
                                                   "mesh-motion scenes; else `layers`)")


TUNE_PARAMETRIZATIONS = ("layers", "profile")
TUNE_ALGORITHMS = ("SLSQP", "MMA", "CCSAQ", "LBFGS")


@dataclass(frozen=True)
class TuneSettings:
    """Stiffening factors tuned by gradients (table ``[tune]``, ``tofsi tune``; see :mod:`tofsi.tuning`)."""

    parametrization: str = option("layers", choices=TUNE_PARAMETRIZATIONS,
                                  doc="layers: one factor per element layer from the interface; "
                                      "profile: f_k = 1 + a exp(-(k - 1) / L) on every layer k (design a, L)")
    layers: int = option(12, ge=1, le=1000, doc="number of tuned layers (parametrization layers)")
    ks: tuple[float, ...] = option((60.0, 240.0), gt=0, doc="Kreisselmeier-Steinhauser parameters of the soft "
                                   "minimum of the corner skewness: one optimization stage each")
    min_factor: float = option(1.0, gt=0, doc="smallest tuned factor (profile: smallest 1 + a)")
    max_factor: float = option(20.0, gt=0, le=MAX_STIFFENING, doc="largest tuned factor (profile: largest 1 + a)")
    min_area_change: float = option(0.0, ge=0, doc="constraint: soft minimum of the area change >= "
                                                   "this (0: no constraint)")
    max_area_change: float = option(0.0, ge=0, doc="constraint: soft maximum of the area change <= "
                                                   "this (0: no constraint)")
    algorithm: str = option("CCSAQ", choices=TUNE_ALGORITHMS, doc="NLopt gradient algorithm (LD_*)")
    max_solves: int = option(24, ge=2, le=100_000, doc="largest number of mover solves, forward moves "
                             "and adjoint solves (vector-Jacobian products) together")
    tol_objective: float = option(1e-4, gt=0, doc="stop on an absolute change of the soft minimum below")

    def __post_init__(self):
        if not self.ks:
            raise InputError("ks", list(self.ks), "give at least one KS parameter, e.g. [60.0]")
        if self.min_factor >= self.max_factor:
            raise InputError("max_factor", self.max_factor,
                             f"allowed: max_factor > min_factor = {self.min_factor}")
        if self.min_area_change and self.max_area_change and self.min_area_change >= self.max_area_change:
            raise InputError("max_area_change", self.max_area_change,
                             f"allowed: 0 or > min_area_change = {self.min_area_change}")
