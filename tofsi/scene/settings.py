"""Settings of a scene's design, optimizer, coupled solve, linear algebra and stiffening tuning.

Each class is one TOML table of a scene file (``[design]``, ``[optimizer]``,
``[coupled]``, ``[solver]``, ``[tune]``); every field states its unit and range.
The fields' own tables (``[fluid]``, ``[structure]``, ``[mover]``) live with
their fields (:mod:`tofsi.fields`).
"""

from __future__ import annotations

from dataclasses import dataclass

from tofsi.core.config import option
from tofsi.core.errors import InputError
from tofsi.core.registry import MATERIALS, OBJECTIVES
from tofsi.linalg.iterative import TRANSPOSE_TOL

MAX_STIFFENING = 1e6
"""Largest stiffening factor of an element layer. Far beyond it a layer is rigid to round-off:
measured on the foil rotated 30 degrees (one stiffened layer), the Yeoh mover's minimum
skewness is 0.585 at a factor 1e3 and 0.562 at 1e6, and its Newton fails from 1e8 on (the
tangent's conditioning grows with the factor); the linear and spring movers change by less
than 0.02 between 1e3 and 1e30."""


@dataclass(frozen=True)
class CoupledSettings:
    """The two-way coupled solve (table ``[coupled]``)."""

    renamed_keys = {"linear_solver": "jacobian_solver"}     # the old name, accepted with a warning

    method: str = option("auto", choices=("auto", "partitioned", "monolithic"),
                         doc="fixed point (Gauss-Seidel sweeps, the next u by the interface quasi-Newton method IQN-ILS), or Newton on the block Jacobian "
                             "(every field needs a residual form; a mover in increments on the updated mesh "
                             "enters as x - M(u)); auto: monolithic when every field has one (every built-in "
                             "mover), partitioned otherwise")
    tol: float = option(1e-9, gt=0, lt=1, doc="relative change of u (partitioned) or residual "
                                               "per block (monolithic)")
    max_iter: int = option(60, ge=1, le=10_000, doc="coupling iterations")
    relaxation: float = option(0.5, gt=0, le=1, doc="partitioned: the relaxation factor of the first sweep (IQN-ILS from the second)")
    quasi_newton: bool = option(True, doc="monolithic: keep the shape derivatives (F_x, S_x) of the "
                                          "first iterate for the rest of the Newton solve (the "
                                          "adjoint gets the exact ones of the converged state)")
    load_ramp: bool = option(True, doc="when a two-way coupled solve fails at the full inflow from its warm "
                                       "start, ramp the inflow from rest in adaptive steps (each warm-"
                                       "started from the last, halved on failure) to carry it to large "
                                       "motion")
    min_load_step: float = option(1.0 / 64.0, ge=1e-6, le=1, doc="the smallest step of the inflow ramp "
                                  "(fraction of the inflow) before the solve fails (at least 1e-6: some 20 "
                                  "halvings of the first step, each failed step a coupled solve)")
    jacobian_solver: str = option("block", choices=("block", "direct"),
                                doc="monolithic: the Newton's linear solver -- block: GMRES preconditioned "
                                    "by block Gauss-Seidel over the fields' own factorizations (flow, "
                                    "structure, mesh); direct: the LU of the whole coupled Jacobian (not for "
                                    "a mover in increments, whose coupling is known by its products). Both "
                                    "converge to the same solution; block is faster, direct the fallback")


@dataclass(frozen=True)
class DesignSettings:
    """Density design: objective, volume, filter and projection (table ``[design]``)."""

    objective: str = option("compliance", choices=OBJECTIVES,
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
    structure_model: tuple[str, ...] = option((), choices=MATERIALS,
                                              doc="structure material of each stage (last value kept): "
                                                  "small strain while the design is gray (a gray start is "
                                                  "no physical state either way, and finite strain crushes "
                                                  "it), finite strain once the topology exists; empty: "
                                                  "structure.model throughout")
    stage_iterations: int = option(40, ge=1, le=10_000, doc="optimizer iterations per continuation stage")
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
    max_iter: int = option(200, ge=1, le=10_000, doc="largest number of design iterations (at most 10 000: "
                                                      "the history is rewritten after each)")
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
    adjoint_tol: float = option(TRANSPOSE_TOL, gt=0, lt=1e-2,
                                doc="iterative path: relative tolerance (scaled residual) of the flow's "
                                    "transposed GMRES, the adjoint's solve; 3e-6 leaves the gradient "
                                    "about 3e-6-2.5e-5 off the LU's and the optimization at the direct "
                                    "path's design (docs/parallel.md); tofsi check-gradients uses 1e-10. "
                                    "The direct backends solve exactly")
    max_memory_gb: float = option(0.0, ge=0, doc="refuse a solve whose estimated memory exceeds "
                                                 "this [GB] (0: the machine's available memory)")
    flow_amg: str = option("hypre", choices=("hypre", "gamg"),
                           doc="AMG of the velocity block of the distributed flow (tofsi optimize of a "
                               "flow-only scene under mpiexec, docs/parallel.md): hypre's BoomerAMG or "
                               "PETSc's GAMG")


TUNE_PARAMETRIZATIONS = ("layers", "profile")
TUNE_ALGORITHMS = ("SLSQP", "MMA", "CCSAQ", "LBFGS")


@dataclass(frozen=True)
class TuneSettings:
    """Stiffening factors tuned by gradients (table ``[tune]``, ``tofsi tune``; see :mod:`tofsi.optimization.tuning`)."""

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
