"""The block protocol is open: fields defined here, in the test file alone, join the system.

Two toy fields on the Q1 nodes, loaded by the structure and coupled to each other (a
cycle of their own, downstream of the structure):

    R_s(s; u, t, rho) = (L + diag(1 + m(rho))) s - G u - 0.2 t = 0,   s_0 = 0 (Dirichlet)
    R_t(t; s)          = t - 0.3 A s = 0

with ``L`` the graph Laplacian of the mesh edges, ``m(rho)`` the mean density of the
elements at a node (squared: nonlinear in rho), ``G u`` the horizontal structural
displacement per node (scaled) and ``A`` the node averaging over elements. The quantity
``f = compliance + |s|^2 + sum t`` is differentiated by the generic adjoint, which never
saw these fields; a Taylor test (rate > 1.9) checks the gradient with respect to rho.
"""

import numpy as np
import pytest
import scipy.sparse as sp

from adjoint import Adjoint
from adjoint.checks import check_blocks, taylor_test
from tofsi.core.blocks import FieldBlock, Linearization
from tofsi.coupling.coupled import CoupledModel
from tofsi.linalg import DirectSolver
from tofsi.objectives.compliance import Compliance

from conftest import load

BASE = ["mesh.h_min=0.1", "mesh.h_max=0.1", "fluid.alpha_max=1e3", "fluid.newton_tol=1e-13",
        "structure.youngs_modulus=2e4", "coupled.tol=1e-12", "mover.yeoh.newton_tol=1e-13",
        "design.beta=[0.0]"]
GAIN = 1e3                       # G u ~ s: the structure moves ~1e-3 m


class ToyLinearization(Linearization):
    def matrix(self):
        return self.block.matrix(self.rho)

    def solve(self, b):
        return DirectSolver(self.matrix()).solve(b)

    def solve_transpose(self, b):
        return DirectSolver(self.matrix()).solve_transpose(b)

    def coupling(self, other):
        return self.block.coupling(other)

    def density(self):
        return self.block.density(self.value, self.rho)


class ToyField(FieldBlock):
    """A linear field with fixed dofs ``fixed_nodes`` (value 0), residual ``A(rho) z - sum C_o z_o``."""

    def __init__(self, name, mesh, inputs, couplings, uses_rho):
        self.name, self.symbol, self.inputs = name, name.upper(), inputs
        self.size = mesh.n_nodes
        self.couplings, self.uses_rho = couplings, uses_rho
        inc = mesh.incidence                                      # (E, n)
        self.average = sp.diags(1.0 / np.asarray(inc.sum(axis=0)).ravel()) @ inc.T   # (n, E)
        q = mesh.quads
        edges = np.vstack([q[:, [0, 1]], q[:, [1, 2]], q[:, [2, 3]], q[:, [3, 0]]])
        adj = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(self.size,) * 2)
        adj = ((adj + adj.T) > 0).astype(float)
        self.laplacian = sp.diags(np.asarray(adj.sum(axis=1)).ravel()) - adj
        self._fixed = np.array([0]) if uses_rho else np.array([], dtype=int)

    @property
    def fixed(self):
        return self._fixed

    def matrix(self, rho):
        if not self.uses_rho:
            return sp.identity(self.size, format="csr")
        m = self.average @ rho
        A = (self.laplacian + sp.diags(1.0 + m**2)).tolil()
        A[self._fixed, :] = 0.0
        A[self._fixed, self._fixed] = 1.0
        return A.tocsr()

    def coupling(self, other):
        C = -self.couplings[other]
        C = C.tolil()
        C[self._fixed, :] = 0.0
        return C.tocsr()

    def density(self, z, rho):
        if not self.uses_rho:
            return None
        D = sp.diags(2.0 * (self.average @ rho) * z) @ self.average
        D = D.tolil()
        D[self._fixed, :] = 0.0
        return D.tocsr()

    def initial(self, fields, rho, params):
        return np.zeros(self.size)

    def residual(self, fields, rho, params):
        r = self.matrix(rho) @ fields[self.name]
        for other in self.inputs:
            r = r + self.coupling(other) @ fields[other]
        return r

    def linearize(self, fields, rho, params):
        return ToyLinearization(self, fields, rho, params)

    def solve(self, fields, rho, params, guess=None, previous=None, progress=None):
        rhs = -sum((self.coupling(o) @ fields[o] for o in self.inputs), np.zeros(self.size))
        z = DirectSolver(self.matrix(rho)).solve(rhs)
        return z, ToyLinearization(self, {**fields, self.name: z}, rho, params), None


def toy_fields(mesh):
    n = mesh.n_nodes
    G = GAIN * sp.csr_matrix((np.ones(n), (np.arange(n), 2 * np.arange(n))), shape=(n, 2 * n))
    s = ToyField("s", mesh, ("u", "t"), {"u": G, "t": 0.2 * sp.identity(n, format="csr")}, True)
    inc = mesh.incidence
    A = sp.diags(1.0 / np.asarray(inc.sum(axis=0)).ravel()) @ (inc.T @ inc) / 4.0
    t = ToyField("t", mesh, ("s",), {"s": 0.3 * A.tocsr()}, False)
    return s, t


def quantity(model, state):
    c = Compliance()
    partials = c.partials(model, state)
    s, t = state.fields["s"], state.fields["t"]
    partials.update({"s": 2 * s, "t": np.ones(t.size)})
    return c.value(model, state) + s @ s + t.sum(), partials


CASES = {"one-way": [],
         "two-way partitioned": ["effects.coupling=two-way", "mover.name=yeoh", "coupled.method=partitioned"],
         "two-way monolithic": ["effects.coupling=two-way", "mover.name=yeoh", "coupled.method=monolithic"]}


@pytest.mark.parametrize("case", list(CASES))
def test_a_field_defined_in_a_test_passes_the_taylor_test_through_the_generic_adjoint(case):
    scene = load("beam_in_channel_optimization", *BASE, *CASES[case])
    model = CoupledModel(scene)
    system = model.system.with_blocks(*toy_fields(model.mesh))
    assert set(system.names) == {"w", "u", "s", "t"} | ({"x"} if "two-way" in case else set())
    assert ("s", "t") in system.components or ("t", "s") in system.components
    rng = np.random.default_rng(3)
    c = model.mesh.centroids[model.design_elements]
    rho = model.densities(rng.uniform(0.2, 0.8, c.shape[0]))

    def value(r):
        state = system.solve(r, model.params)
        return quantity(model, state)[0]
    state = system.solve(rho, model.params)
    f0, partials = quantity(model, state)
    adjoint = Adjoint(system, state)
    grad = adjoint.gradient(partials)
    assert np.any(grad[model.design_elements])
    if "monolithic" in case:                       # both cycles by the monolithic adjoint
        assert [r["method"] for r in adjoint.reports] == ["monolithic", "monolithic"]
    d = np.zeros_like(rho)
    d[model.design_elements] = rng.normal(size=model.design_elements.size)
    t = taylor_test(value, rho, grad, d, eps0=1e-2, steps=4, f0=f0)
    assert t.min_rate > 1.9, t
    without = Adjoint(system, state).gradient({**partials, "s": None})   # teeth: drop a term
    assert taylor_test(value, rho, without, d, eps0=1e-2, steps=4, f0=f0).min_rate < 1.3
    rows = check_blocks(system, state)
    assert {r["check"] for r in rows} >= {"S_s", "S_u", "S_t", "S_rho", "T_t", "T_s"}
    assert all(r["passed"] for r in rows), [r for r in rows if not r["passed"]]
