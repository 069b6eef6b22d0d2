"""Density-based design of a scene: gamma -> rho -> coupled state -> objective and constraints.

    problem = tofsi.Problem(scene)
    gamma = problem.initial_design()
    f, df = problem.evaluate(gamma)          # objective and its gradient
    g, dg = problem.constraints(gamma)       # g <= 0 is feasible, dg: (m, n_design)

One forward solve and one adjoint solve per quantity at each new design,
cached, because an optimizer asks for the objective and every constraint at
the same point. The previous state warm-starts the next forward solve.
Continuation parameters (projection sharpness, SIMP penalty, Brinkman q) are
set with :meth:`Problem.set_stage`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from adjoint import Adjoint
from tofsi.coupled import CoupledModel, State
from tofsi.design import DesignMap
from tofsi.errors import InputError
from tofsi.interpolation import SIMP
from tofsi.linalg import RecyclingSolver
from tofsi.objectives import OBJECTIVES, VolumeFraction


class Problem:
    """The design problem of a scene with a design region."""

    def __init__(self, scene, mesh=None):
        if not scene.has_design:
            raise InputError("geometry.design", [], "a design problem needs a design region")
        self.scene = scene
        self.model = CoupledModel(scene, mesh)
        d = scene.design
        needs = {"compliance": "structure", "dissipation": "fluid", "dissipation-strain": "fluid",
                 "pressure-drop": "fluid"}[d.objective]
        if getattr(scene.effects, needs) == "none":
            raise InputError("design.objective", d.objective, f"needs effects.{needs}")
        self.map = DesignMap(self.model.mesh, d.filter_radius, d.beta[0], d.eta)
        self.objective = OBJECTIVES[d.objective]()
        self.volume_fraction = VolumeFraction(self.model.mesh, self.map.design)
        self._cache: dict = {}
        self._guess: State | None = None
        self.evaluations = 0
        self.initial_design()                      # a bad design.initial fails here, early

    @property
    def n_design(self) -> int:
        return self.map.size

    def initial_design(self) -> np.ndarray:
        """``design.initial`` if given (a saved design), else uniform at the volume bound."""
        path = self.scene.design.initial
        if not path:
            fraction = self.scene.design.volume_fraction
            return np.full(self.n_design, fraction if self.scene.design.constraint == "solid" else 1 - fraction)
        from pathlib import Path
        if not Path(path).is_file():
            raise InputError("design.initial", path, "no such file (a design.npy of an earlier run)")
        try:
            gamma = np.load(path)
        except (ValueError, OSError) as err:
            raise InputError("design.initial", path, f"not a NumPy array file ({err})") from None
        if gamma.shape != (self.n_design,) or not np.all(np.isfinite(gamma)):
            raise InputError("design.initial", path, f"needs {self.n_design} finite values (this scene's "
                                                     "design variables), got shape " + str(gamma.shape))
        return np.clip(gamma, 0.0, 1.0)

    def set_stage(self, beta: float | None = None, penalty: float | None = None, q: float | None = None):
        """Change continuation parameters (the cache is cleared)."""
        if beta is not None:
            self.map = self.map.with_beta(beta)
        if penalty is not None and self.model.structure is not None:
            s = self.model.structure.simp
            self.model.structure.simp = SIMP(s.E0, s.Emin, penalty)
        if q is not None:
            flow = self.model.flow
            flow.brinkman = dataclasses.replace(flow.brinkman, q=q)
        self._cache.clear()

    def reset_solvers(self) -> None:
        """Forget recycled factorizations, so that the next solve depends only on its inputs
        (bitwise reproducible runs, also after a resume)."""
        flow = self.model.flow
        flow.solver = RecyclingSolver(flow._factorize)
        self.model._newton_solver = None

    def set_guess(self, state: State | None) -> None:
        """The state the next forward solve starts from."""
        self._guess = state

    # ---- evaluation -------------------------------------------------------------------
    def densities(self, gamma) -> np.ndarray:
        return self.map.forward(np.asarray(gamma, dtype=float))

    def solve(self, gamma) -> State:
        """The coupled state of design ``gamma`` (cached)."""
        return self._entry(gamma)["state"]

    def _entry(self, gamma) -> dict:
        gamma = np.asarray(gamma, dtype=float)
        if gamma.shape != (self.n_design,):
            raise ValueError(f"gamma must have {self.n_design} entries")
        if not np.all(np.isfinite(gamma)):
            raise InputError("gamma", "non-finite", "design variables must be finite")
        key = gamma.tobytes()
        if key not in self._cache:
            rho = self.densities(gamma)
            state = self.model.solve(rho, self._guess)
            self._guess = state
            self._cache.clear()
            self._cache[key] = {"state": state, "gamma": gamma.copy()}
            self.evaluations += 1
        return self._cache[key]

    def _adjoint(self, entry) -> Adjoint:
        if "adjoint" not in entry:
            entry["adjoint"] = Adjoint(self.model, entry["state"])
        return entry["adjoint"]

    def evaluate(self, gamma) -> tuple[float, np.ndarray]:
        """Objective and its gradient with respect to gamma."""
        entry = self._entry(gamma)
        if "objective" not in entry:
            state = entry["state"]
            f = self.objective.value(self.model, state)
            df_drho = self._adjoint(entry).gradient(self.objective)
            entry["objective"] = (f, self.map.transpose(entry["gamma"], df_drho))
        return entry["objective"]

    def constraints(self, gamma) -> tuple[np.ndarray, np.ndarray]:
        """``g = [phase fraction / volume_fraction - 1] <= 0`` and ``dg/dgamma`` (1, n_design).

        The phase is the solid (``design.constraint = "solid"``) or the fluid
        (``"fluid"``: fraction ``1 - solid``) of the design region.
        """
        entry = self._entry(gamma)
        if "constraints" not in entry:
            state = entry["state"]
            d = self.scene.design
            solid = self.volume_fraction.value(self.model, state)
            dsolid = self.map.transpose(entry["gamma"], self._adjoint(entry).gradient(self.volume_fraction))
            sign, fraction = (1.0, solid) if d.constraint == "solid" else (-1.0, 1.0 - solid)
            g = fraction / d.volume_fraction - 1.0
            entry["constraints"] = (np.array([g]), sign * dsolid[None, :] / d.volume_fraction)
        return entry["constraints"]

    def volume(self, gamma) -> float:
        """Solid fraction of the design region."""
        return self.volume_fraction.value(self.model, self.solve(gamma))
