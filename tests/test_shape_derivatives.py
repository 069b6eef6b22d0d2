"""Analytic shape derivatives against the complex step (the oracle).

``tofsi.physics.fluid_shape`` differentiates the element integrands by hand
(d det J = det J g_km, d grad N = -grad N_m g_k, ...). The oracle is the
complex step through the residual and load kernels themselves -- exact to
round-off, sharing none of the derivative code: per element through the
kernels that take corners ``Xe`` (``corner_derivatives``), and for whole
blocks through the public functions of the mesh displacement ``x`` with the
nodes in four colours (every element has one corner of each colour, so one
complex evaluation per colour and direction gives every element's column).
Agreement is asked to 1e-10 relative to the largest entry, on distorted
elements, gray densities, Stokes and Navier-Stokes, both viscous forms.
"""

from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp

from tofsi.core.blocks import Continuation
from tofsi.fem.assembly import element_dofs
from tofsi.fem.complex_step import COMPLEX_STEP, corner_derivatives
from tofsi.mesh.structured import StructuredQuadMesh
from tofsi.objectives.compliance import Compliance
from tofsi.objectives.dissipation import Dissipation
from tofsi.physics.fluid_kernel import brinkman_partial, fluid_element
from tofsi.physics.fluid_load import load_operator
from tofsi.physics.fluid_shape import dissipation_shape, fluid_shape, mass_shape, stress_load_shape
from tofsi.physics.flow import Flow
from tofsi.physics.structure import Structure
from tofsi.fields.flow import FluidSettings
from tofsi.fields.structure import StructureSettings

TOL = 1e-10
PARAMS = Continuation(brinkman_q=0.3, load_exponent=3.0)


def relative(a, b) -> float:
    return float(np.abs(np.asarray(a) - b).max() / np.abs(b).max())


def distorted_elements(rng, E=12):
    """Random convex quads: stretched squares with corners moved by up to 30 % of the size."""
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    size = rng.uniform(0.2, 2.0, (E, 1, 2))
    return square * size + 0.3 * size * rng.uniform(-0.5, 0.5, (E, 4, 2)) + rng.normal(size=(E, 1, 2))


def element_state(rng, E):
    return (rng.normal(size=(E, 9, 2)), rng.normal(size=(E, 4)),
            rng.uniform(0.0, 30.0, E))          # gray: any friction between fluid and solid


# ---- element kernels ----------------------------------------------------------------------
@pytest.mark.parametrize("symmetric", [False, True], ids=["gradient", "symmetric"])
@pytest.mark.parametrize("density", [0.0, 1.7], ids=["stokes", "navier-stokes"])
def test_fluid_residual_shape_derivative_equals_the_complex_step(density, symmetric):
    rng = np.random.default_rng(3)
    Xe = distorted_elements(rng)
    ve, pe, alpha = element_state(rng, len(Xe))
    Re, dR = fluid_shape(Xe, ve, pe, alpha, density, 0.6, symmetric)
    residual = lambda X: fluid_element(X, ve, pe, alpha, density, 0.6, symmetric, jacobian=False)[0]
    assert relative(Re, residual(Xe)) < 1e-14
    oracle = corner_derivatives(residual, Xe)
    assert relative(dR[:, :18], oracle[:, :18]) < TOL           # momentum rows
    assert relative(dR[:, 18:], oracle[:, 18:]) < TOL           # continuity rows
    assert np.abs(oracle).max() > 1.0                            # the oracle is not trivially zero


def test_load_and_dissipation_kernels_equal_the_complex_step():
    rng = np.random.default_rng(4)
    Xe = distorted_elements(rng)
    ve, pe, alpha = element_state(rng, len(Xe))
    mu = 0.6
    assert relative(mass_shape(Xe, ve), corner_derivatives(lambda X: brinkman_partial(X, ve)[:, :18], Xe)) < TOL
    we = np.concatenate([ve.reshape(len(Xe), 18), pe], axis=1)
    stress = corner_derivatives(lambda X: np.einsum("eab,eb->ea", load_operator(X, mu), we), Xe)
    assert relative(stress_load_shape(Xe, ve, pe, mu), stress) < TOL

    def dissipation(X):                         # written from the definition, not the library's
        from tofsi.fem.geometry import physical_gradients
        from tofsi.physics.fluid_kernel import N2, POINTS, WEIGHTS
        grad, det = physical_gradients(X, 2, POINTS)
        L = np.einsum("ebi,egbj->egij", ve, grad)
        v = np.einsum("gb,ebi->egi", N2, ve)
        integrand = mu * np.einsum("egij,egij->eg", L, L) + alpha[:, None] * np.einsum("egi,egi->eg", v, v)
        return 0.5 * np.sum(integrand * det * WEIGHTS, axis=1)
    assert relative(dissipation_shape(Xe, ve, alpha, mu), corner_derivatives(dissipation, Xe)) < TOL


# ---- blocks on a moved mesh -------------------------------------------------------------------
def coloured_derivatives(fn, mesh, x):
    """``d fn(x)_e / dX_e`` ``(E, ..., 8)`` for element values ``fn(x)`` ``(E, ...)`` of the mesh
    displacement ``x`` (n, 2), by the complex step with the nodes in four colours."""
    colour = (mesh.grid_positions() // 2 % 2) @ np.array([1, 2])
    corner_colour = colour[mesh.quads]                                 # (E, 4): a permutation of 0..3
    E = mesh.n_elements
    out = None
    for c in range(4):
        corner = np.argmax(corner_colour == c, axis=1)                  # each element's corner of colour c
        for m in range(2):
            xc = x.astype(complex)
            xc[colour == c, m] += 1j * COMPLEX_STEP
            d = np.asarray(fn(xc)).imag / COMPLEX_STEP
            if out is None:
                out = np.zeros(d.shape + (8,))
            out[np.arange(E), ..., 2 * corner + m] = d
    return out


def scatter(rows, cols, values, shape):
    """A sparse matrix summed from element blocks (COO: independent of the library's patterns)."""
    r = np.broadcast_to(rows[:, :, None], values.shape).ravel()
    c = np.broadcast_to(cols[:, None, :], values.shape).ravel()
    return sp.csr_matrix((values.ravel(), (r, c)), shape=shape)


def moved_channel(rng, **fluid):
    mesh = StructuredQuadMesh(np.array([0.0, 0.3, 0.7, 1.2, 1.5]), np.array([0.0, 0.4, 1.0, 1.3]))
    X = mesh.points
    x = 0.05 * np.column_stack([np.sin(3 * X[:, 0] + X[:, 1]), np.cos(2 * X[:, 1] - X[:, 0])])
    x += 0.02 * rng.uniform(-1, 1, x.shape)                            # no two elements alike
    flow = Flow(mesh, FluidSettings(viscosity=0.6, alpha_max=40.0, alpha_min=0.5, **fluid))
    w = rng.normal(size=flow.size)
    rho = rng.uniform(0.05, 0.95, mesh.n_elements)
    return mesh, flow, w, x, rho


@pytest.mark.parametrize("outlet", ["zero-pressure", "traction-free"])
@pytest.mark.parametrize("density", [0.0, 1.3], ids=["stokes", "navier-stokes"])
def test_flow_shape_partial_equals_the_complex_step(density, outlet):
    rng = np.random.default_rng(5)
    mesh, flow, w, x, rho = moved_channel(rng, density=density, outlet=outlet)
    flow.shape_partial(w, x, 1.0 - rho, PARAMS)                       # another point first: nothing kept
    Fx = flow.shape_partial(w, x, rho, PARAMS)
    oracle = coloured_derivatives(lambda xc: flow.element_residual(w, xc, rho, jacobian=False,
                                                                   params=PARAMS)[0], mesh, x)
    expected = scatter(flow.dofs, element_dofs(mesh.quads, 2), oracle, Fx.shape)
    assert abs(Fx - expected).max() < TOL * abs(expected).max()


def test_flow_shape_partial_with_a_body_force_includes_the_force():
    rng = np.random.default_rng(6)
    mesh, _, w, x, rho = moved_channel(rng, density=1.0)
    force = lambda P: np.stack([np.sin(4 * P[..., 1]), P[..., 0] ** 2], axis=-1) * 30.0
    flow = Flow(mesh, FluidSettings(viscosity=0.6, alpha_max=40.0), body_force=force)
    oracle = coloured_derivatives(lambda xc: flow.element_residual(w, xc, rho, jacobian=False)[0], mesh, x)
    expected = scatter(flow.dofs, element_dofs(mesh.quads, 2), oracle, (flow.size, 2 * mesh.n_nodes))
    Fx = flow.shape_partial(w, x, rho)
    assert abs(Fx - expected).max() < TOL * abs(expected).max()
    without = Flow(mesh, FluidSettings(viscosity=0.6, alpha_max=40.0)).shape_partial(w, x, rho)
    assert abs(Fx - without).max() > 1e-3 * abs(expected).max()       # the force's part is there


@pytest.mark.parametrize("load", ["reaction", "stress-divergence"])
def test_fluid_load_shape_partial_equals_the_complex_step(load):
    rng = np.random.default_rng(7)
    mesh, flow, w, x, rho = moved_channel(rng, density=1.1)
    force = Structure(mesh, StructureSettings(youngs_modulus=3.0, load=load), flow).force
    oracle = coloured_derivatives(lambda xc: force.elements(w, xc, rho, PARAMS)[0], mesh, x)   # (E, 8, 8)
    expected = scatter(force.dofs, force.dofs, oracle, (force.size, force.size))
    Sx = force.shape_partial(w, x, rho, PARAMS)
    assert abs(Sx - expected).max() < TOL * abs(expected).max()
    lam = rng.normal(size=force.size)
    assert relative(force.shape_partial_transpose(lam, w, x, rho, PARAMS), expected.T @ lam) < TOL


@pytest.mark.parametrize("load", ["reaction", "stress-divergence"])
def test_objective_shape_partials_equal_the_complex_step(load):
    rng = np.random.default_rng(8)
    mesh, flow, w, x, rho = moved_channel(rng, density=0.9)
    structure = Structure(mesh, StructureSettings(youngs_modulus=3.0, load=load), flow)
    u = rng.normal(size=structure.size)
    model = SimpleNamespace(flow=flow, structure=structure, mesh=mesh, two_way=True)
    state = SimpleNamespace(w=w, u=u, rho=rho, params=PARAMS, mesh_displacement=x, x=x.ravel())
    ue = u[structure.dofs]
    values = {"compliance": lambda xc: np.einsum("ea,ea->e", structure.force.elements(w, xc, rho, PARAMS)[0], ue),
              "dissipation": lambda xc: Dissipation.element_values(flow, flow.corners(xc), w, rho, PARAMS)}
    for objective in (Compliance(), Dissipation()):
        oracle = coloured_derivatives(values[objective.name], mesh, x)                          # (E, 8)
        expected = np.bincount(element_dofs(mesh.quads, 2).ravel(), oracle.ravel(), minlength=2 * mesh.n_nodes)
        assert relative(objective.partials(model, state)["x"], expected) < TOL, objective.name
