"""The fluid's force on the solid phase in the unified Brinkman domain, on the Q1 (structure) nodes.

Three forms (scene key ``structure.load``), all functions of the flow state:

``reaction`` (default) -- the momentum-consistent reaction. Per element, on the
velocity rows ``b`` (Q2 or, for equal order, Q1 nodes) that are not Dirichlet (``free``),

    rows_e = (alpha_e - alpha_min) A_e w_e + psi_e (R_e(w_e) - alpha_e A_e w_e),
    f_(a i) = sum_e sum_b T_ba rows_e(b i),

with ``R_e`` the fluid element residual (viscous, pressure, convection and
Brinkman terms), ``A_e w_e = int N_b v_i`` its Brinkman part per unit
friction, ``psi_e = rho_e^k`` and ``T_ba = M_a(x_b)`` the Q1 shape functions
at the velocity nodes (``M_a = sum_b T_ba N_b``), so ``f`` is the residual tested with
the structure's shape functions. For 0/1 densities and a converged flow it is
minus the fluid elements' residual on the solid's boundary rows: the
reaction force of the Brinkman state on the body, node by node. As the
friction grows the Brinkman state tends to the no-slip state on the same
mesh and the load to the no-slip body's reaction (error ~ mu / (alpha h^2);
see ``docs/design.md``); Dirichlet rows (a wall under a clamped solid) carry
no load, and the resultant is the drag and lift. Gray elements carry their
Brinkman exchange plus ``psi`` times their own stress residual, smooth in rho.
(The equal-order element's stabilization terms belong to ``R_e``; its friction
derivative ``dR_e/dalpha`` is the element's own, ``tau`` included.)

``stress-divergence`` -- Lundgaard et al. (2018, eq. 3) with the viscous
stress added (Abdelhamid & Czekanski's total stress):

    f_(a i) = sum_e psi_e int_e [sigma_ij dM_a/dx_j + M_a d sigma_ij/dx_j],
    sigma = -p I + mu (grad v + grad v^T),

evaluated inside the solid, where the unresolved Brinkman layer loses most of
the viscous shear (kept to reproduce published results). It is linear in
``w``: ``f_e = psi_e B_e(Xe) w_e``.

``pressure`` -- the same volume form with the pressure alone (TOFLUX's load,
``experiments/fsi/pressure_coupling.py``; its sign there is the opposite, which
changes neither the compliance nor the design):

    f_(a i) = -sum_e psi_e int_e [p dM_a/dx_i + M_a dp/dx_i].

Every form gives its element loads and their partial derivatives with
respect to ``rho`` from the flow's kept element evaluation (no kernel call of
its own); the partial with respect to ``w`` is formed per element only for
the assembled block (two-way Newton), the adjoint's product with its
transpose is taken element by element without it; the partial with respect
to the mesh position is analytic for Taylor-Hood (:mod:`tofsi.physics.fluid_shape`;
the tests check them against the complex step through the same kernels) and
by the complex step for equal order.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from tofsi.core.blocks import Continuation
from tofsi.fem.assembly import SparsePattern, assemble_vector, element_dofs
from tofsi.fem.complex_step import corner_derivatives
from tofsi.fem.geometry import physical_gradients, physical_hessians
from tofsi.fem.shapes import shape_functions
from tofsi.core.kept import Kept, input_key
from tofsi.physics.fluid_elements import TaylorHood

LOAD_FORMS = ("reaction", "stress-divergence", "pressure")


def rows_to_corners(element) -> np.ndarray:
    """``T`` ``(8, 2k)`` with ``f_e = T rows_e``: the velocity rows tested with the Q1 shape
    functions (``T[2a+i, 2b+i] = M_a(x_b)``; the identity for equal order)."""
    return np.kron(element.to_corners.T, np.eye(2))


def load_operator(Xe: np.ndarray, viscosity: float, element=TaylorHood) -> np.ndarray:
    """``B_e`` ``(E, 8, 2k + 4)`` of the stress-divergence form, ``f_e = psi_e B_e w_e``
    (complex-safe); ``viscosity = 0`` gives the pressure-only form."""
    E = Xe.shape[0]
    mu = viscosity
    points, k = element.POINTS, element.nodes_per_element
    N1, _ = shape_functions(1, points)                              # (G, 4)
    gv, det = physical_gradients(Xe, element.degree, points)        # (E, G, k, 2)
    g1, _ = physical_gradients(Xe, 1, points)                       # (E, G, 4, 2)
    Hv = physical_hessians(Xe, element.degree, points, gv)          # (E, G, k, 2, 2)
    w = det * element.WEIGHTS                                       # (E, G)
    G = w.shape[1]
    gw = g1 * w[..., None, None]                                    # (E, G, 4, 2)
    Mw = N1[None] * w[..., None]                                    # (E, G, 4)
    # cross[a, k, b, i] = sum_g dM_a/dx_k dN_b/dx_i  (one product over stacked points)
    cross = np.matmul(gw.reshape(E, G, 8).transpose(0, 2, 1), gv.reshape(E, G, 2 * k)).reshape(E, 4, 2, k, 2)
    dot = cross[:, :, 0, :, 0] + cross[:, :, 1, :, 1]               # grad M_a . grad N_b
    lap = Hv[..., 0, 0] + Hv[..., 1, 1]                             # (E, G, k)
    Mlap = np.matmul(Mw.transpose(0, 2, 1), lap)                    # sum_g M_a lap N_b
    MH = np.matmul(Mw.transpose(0, 2, 1), Hv.reshape(E, G, 4 * k)).reshape(E, 4, k, 2, 2)   # [a, b, k, i]
    B = mu * cross.transpose(0, 1, 4, 3, 2) + mu * MH.transpose(0, 1, 4, 2, 3)           # [a, i, b, k]
    B[:, :, 0, :, 0] += mu * (dot + Mlap)
    B[:, :, 1, :, 1] += mu * (dot + Mlap)
    # pressure: -p dM_a/dx_i - M_a dp/dx_i
    P = -(np.matmul(gw.reshape(E, G, 8).transpose(0, 2, 1), N1).reshape(E, 4, 2, 4)
          + np.matmul(Mw.transpose(0, 2, 1), g1.reshape(E, G, 8)).reshape(E, 4, 4, 2).transpose(0, 1, 3, 2))
    out = np.empty((E, 8, 2 * k + 4), dtype=B.dtype)
    out[:, :, :2 * k] = B.reshape(E, 8, 2 * k)
    out[:, :, 2 * k:] = P.reshape(E, 8, 4)
    return out


def brinkman_mass(Xe: np.ndarray, element=TaylorHood) -> np.ndarray:
    """``int_e N_b N_c`` ``(E, k, k)`` [m^2], the velocity mass per component (complex-safe in ``Xe``)."""
    N = element.N
    _, det = physical_gradients(Xe, 1, element.POINTS)
    return np.matmul((N[None] * (det * element.WEIGHTS)[..., None]).transpose(0, 2, 1), N)


def brinkman_operator(Xe: np.ndarray, element=TaylorHood) -> np.ndarray:
    """``A_e`` ``(E, 2k, 2k + 4)``: ``A[2b+i, 2c+i] = int_e N_b N_c`` [m^2] (complex-safe in ``Xe``)."""
    k = element.nodes_per_element
    NN = brinkman_mass(Xe, element)
    A = np.zeros((Xe.shape[0], 2 * k, 2 * k + 4), dtype=NN.dtype)
    A[:, 0:2 * k:2, 0:2 * k:2] = NN
    A[:, 1:2 * k:2, 1:2 * k:2] = NN
    return A


class FluidForce:
    """The fluid's force on the solid phase of a :class:`~tofsi.physics.flow.Flow` (nodal, on Q1).

    form : ``"reaction"``, ``"stress-divergence"`` or ``"pressure"`` (see the module docstring)
    ``params`` default to :class:`~tofsi.core.blocks.Continuation` (q, load exponent k).
    """

    def __init__(self, flow, form: str = "reaction"):
        if form not in LOAD_FORMS:
            raise ValueError(f"unknown load form {form!r}; one of {LOAD_FORMS}")
        self.flow, self.form = flow, form
        self.element = flow.element
        self.k2 = 2 * flow.element.nodes_per_element                           # velocity rows per element
        self.to_corners = rows_to_corners(flow.element)                        # (8, 2k)
        self.dofs = element_dofs(flow.mesh.quads, 2)                           # (E, 8)
        self.size = 2 * flow.mesh.n_nodes
        self.free = (~flow.bc.is_fixed[flow.dofs[:, :self.k2]]).astype(float)  # (E, 2k)
        self.kept_operators = Kept()      # B of the stress-divergence form on the last mesh
        self.kept_values = Kept()         # element loads (and density partials) of the last evaluation
        self.kept_fluid = Kept()          # df_e/dw_e of the last evaluation (for the assembled df/dw)
        self.kept_parts = Kept()          # the reaction form's pieces at the last state
        self.kept_shape = Kept()          # df_e/dXe of the last shape evaluation
        self._fluid_pattern = None        # CSR patterns of df/dw and df/dx (made on first use)
        self._shape_pattern = None

    @property
    def viscosity(self) -> float:
        """The viscosity in the volume forms [Pa s]: the flow's, read at each use (the pressure
        form: none)."""
        return 0.0 if self.form == "pressure" else self.flow.settings.viscosity

    # ---- weights -----------------------------------------------------------------------
    @staticmethod
    def weight(rho, params: Continuation | None) -> np.ndarray:
        """``psi = rho^k`` per element (``k`` the load exponent)."""
        k = (params or Continuation()).load_exponent
        return np.asarray(rho, dtype=float) ** k

    @staticmethod
    def weight_derivative(rho, params: Continuation | None) -> np.ndarray:
        k = (params or Continuation()).load_exponent
        return k * np.asarray(rho, dtype=float) ** (k - 1.0)

    # ---- element kernels ---------------------------------------------------------------------
    def stress_operators(self, x=None) -> np.ndarray:
        """``B_e`` on the mesh moved by ``x`` (kept, keyed by ``x`` and the viscosity)."""
        mu = self.viscosity
        return self.kept_operators.get(input_key(None if x is None else np.asarray(x), mu),
                                       lambda: load_operator(self.flow.corners(x), mu, self.element))

    def _reaction_parts(self, w, x, rho, params, Xe):
        """The pieces of the reaction form per element: the velocity mass ``NN`` ``(E, k, k)``,
        ``unit = A_e w_e`` ``(E, 2k)``, the friction-free residual ``stress`` ``(E, 2k)``, the
        weights ``alpha``, ``psi`` and the mass coefficient ``c = alpha - alpha_min - psi alpha``
        of ``rows_e = free (c A_e w_e + psi R_e)``; the flow's element residuals are its kept
        evaluation at the same inputs. Kept (read-only), keyed by every input: the load, its
        density partials and the adjoint's product at one state share them."""
        return self.kept_parts.get(self.evaluation_key(w, x, rho, params, False) + ("parts",),
                                   lambda: self._new_reaction_parts(w, x, rho, params, Xe))

    def _new_reaction_parts(self, w, x, rho, params, Xe):
        fl, k2 = self.flow, self.k2
        brinkman = fl.brinkman(params)
        alpha = brinkman(rho)
        psi = self.weight(rho, params)
        Re = fl.element_residuals(w, x, rho, params)
        NN = brinkman_mass(Xe, self.element)
        unit = np.matmul(NN, w[fl.dofs][:, :k2].reshape(len(NN), -1, 2)).reshape(len(NN), k2)   # int N_b v_i
        stress = Re[:, :k2] - alpha[:, None] * unit                            # R_e without friction
        return NN, unit, stress, alpha, psi, alpha - brinkman.alpha_min - psi * alpha

    def _reaction(self, w, x, rho, params, Xe, partials: bool):
        """Element loads ``(E, 8)`` of the reaction form on the mesh moved by ``x`` (corners ``Xe``),
        and with ``partials`` ``df/drho_e (E, 8)``."""
        fl, T = self.flow, self.to_corners
        _, unit, stress, alpha, psi, _ = self._reaction_parts(w, x, rho, params, Xe)
        brinkman = fl.brinkman(params)
        fe = (self.free * ((alpha - brinkman.alpha_min)[:, None] * unit + psi[:, None] * stress)) @ T.T
        if not partials:
            return fe, None
        # d rows/d alpha = free (unit + psi (dR/dalpha - unit)): Taylor-Hood's stress part does not
        # depend on alpha (dR/dalpha = unit); the equal-order stabilization's does
        dR = fl.alpha_vectors(w, x, rho, params)[:, :self.k2]
        dalpha = (self.free * (unit + psi[:, None] * (dR - unit))) @ T.T
        dpsi = (self.free * stress) @ T.T
        return fe, brinkman.derivative(rho)[:, None] * dalpha + self.weight_derivative(rho, params)[:, None] * dpsi

    def evaluation_key(self, w, x, rho, params, partials: bool) -> tuple:
        """Every input of an element evaluation: the flow's (:meth:`Flow.evaluation_key`, its
        settings and density included), the load's form and whether the partials are asked for."""
        return self.flow.evaluation_key(w, x, rho, params) + (self.form, partials)

    def elements(self, w, x, rho, params=None, partials: bool = False):
        """``(f_e (E, 8), df_e/drho_e (E, 8) or None)`` at ``(w, x, rho)``.

        The last evaluation is kept (read-only), keyed by every input; an evaluation with the
        partials also serves a later one without them.
        """
        if not partials:
            both = self.kept_values.peek(self.evaluation_key(w, x, rho, params, True))
            if both is not None:
                return both
        return self.kept_values.get(self.evaluation_key(w, x, rho, params, partials),
                                    lambda: self._elements(w, x, rho, params, partials))

    def _elements(self, w, x, rho, params, partials: bool):
        rho = np.zeros(self.flow.mesh.n_elements) if rho is None else np.asarray(rho, dtype=float)
        if self.form == "reaction":
            return self._reaction(w, x, rho, params, self.flow.corners(x), partials)
        Bw = np.einsum("eab,eb->ea", self.stress_operators(x), w[self.flow.dofs])
        return (Bw * self.weight(rho, params)[:, None],
                Bw * self.weight_derivative(rho, params)[:, None] if partials else None)

    def fluid_elements(self, w, x, rho, params=None) -> np.ndarray:
        """``df_e/dw_e`` ``(E, 8, m)`` at ``(w, x, rho)`` (kept, read-only, keyed by every input):
        reaction ``T free (c A_e + psi K_e)`` with the flow's kept element Jacobians ``K_e``;
        stress forms ``psi_e B_e``. Only the assembled ``df/dw`` needs it; the adjoint's
        product :meth:`fluid_partial_transpose` does not."""
        return self.kept_fluid.get(self.evaluation_key(w, x, rho, params, True),
                                   lambda: self._fluid_elements(w, x, rho, params))

    def _fluid_elements(self, w, x, rho, params):
        rho = np.zeros(self.flow.mesh.n_elements) if rho is None else np.asarray(rho, dtype=float)
        if self.form != "reaction":
            return self.stress_operators(x) * self.weight(rho, params)[:, None, None]
        NN, _, _, _, psi, c = self._reaction_parts(w, x, rho, params, self.flow.corners(x))
        Ke = self.flow.element_jacobians(w, x, rho, params)[1]
        E, k2, m = Ke.shape[0], self.k2, Ke.shape[2]
        rows = psi[:, None, None] * Ke[:, :k2, :]                                # (E, 2k, m)
        mass = c[:, None, None] * NN                                           # c A_e: NN per component
        rows[:, 0:k2:2, 0:k2:2] += mass
        rows[:, 1:k2:2, 1:k2:2] += mass
        rows *= self.free[..., None]
        # T rows: the Q1 weights of the velocity nodes, component by component
        return np.matmul(self.element.to_corners.T, rows.reshape(E, k2 // 2, 2 * m)).reshape(E, 8, m)

    # ---- global quantities ----------------------------------------------------------------------
    def load(self, w, x=None, rho=None, params=None) -> np.ndarray:
        """Nodal load ``f`` (2n,) [N/m] on the Q1 nodes."""
        return assemble_vector(self.dofs, self.elements(w, x, rho, params)[0], self.size)

    def resultant(self, w, x=None, rho=None, params=None) -> tuple[float, float]:
        """Drag and lift [N/m]: the load's resultant (the Q1 shape functions sum to one)."""
        fe = self.elements(w, x, rho, params)[0]
        return float(fe[:, 0::2].sum()), float(fe[:, 1::2].sum())

    def fluid_partial(self, w, x, rho, params=None) -> sp.csr_matrix:
        """``df/dw`` (2n x size of w)."""
        if self._fluid_pattern is None:
            self._fluid_pattern = SparsePattern(self.dofs, self.flow.dofs, (self.size, self.flow.size))
        return self._fluid_pattern.assemble(self.fluid_elements(w, x, rho, params))

    def fluid_partial_transpose(self, lam, w, x, rho, params=None) -> np.ndarray:
        """``(df/dw)^T lam`` (size of w) element by element, without forming ``df_e/dw_e``: with
        ``nu_e = free (T^T lam_e)``, the reaction form's is ``psi_e K_e^T nu_e + c_e A_e^T nu_e``
        (``A_e^T nu_e`` is the velocity mass on each component), the stress forms' ``psi_e B_e^T lam_e``."""
        fl = self.flow
        rho = np.zeros(fl.mesh.n_elements) if rho is None else np.asarray(rho, dtype=float)
        lam_e = lam[self.dofs]                                                   # (E, 8)
        if self.form != "reaction":
            ve = np.einsum("eab,ea->eb", self.stress_operators(x), lam_e) * self.weight(rho, params)[:, None]
            return assemble_vector(fl.dofs, ve, fl.size)
        NN, _, _, _, psi, c = self._reaction_parts(w, x, rho, params, fl.corners(x))
        Ke = fl.element_jacobians(w, x, rho, params)[1]
        nu = self.free * (lam_e @ self.to_corners)                               # (E, 2k)
        ve = psi[:, None] * np.einsum("ea,eab->eb", nu, Ke[:, :self.k2, :])
        mass = np.matmul(np.swapaxes(NN, 1, 2), nu.reshape(len(nu), -1, 2)).reshape(len(nu), self.k2)
        ve[:, :self.k2] += c[:, None] * mass
        return assemble_vector(fl.dofs, ve, fl.size)

    def density_vectors(self, w, x, rho, params=None) -> np.ndarray:
        """``df_e/drho_e`` ``(E, 8)``."""
        return self.elements(w, x, rho, params, partials=True)[1]

    def shape_elements(self, w, x, rho, params=None) -> np.ndarray:
        """``df_e/dXe`` ``(E, 8, 8)``, analytic (:mod:`tofsi.physics.fluid_shape`).

        Reaction form: ``d rows_e = free ((alpha - alpha_min - psi alpha) d(A_e w_e) + psi dR_e)``
        with the flow's ``dR_e/dXe`` (:meth:`~tofsi.physics.flow.Flow.shape_elements`, shared
        with ``F_x``); stress-divergence form: ``psi_e d(B_e w_e)``. The last evaluation is
        kept (read-only), keyed by every input (``S_x`` and its transposed product at one state
        share it).
        """
        return self.kept_shape.get(self.evaluation_key(w, x, rho, params, False),
                                   lambda: self._shape_elements(w, x, rho, params))

    def _shape_elements(self, w, x, rho, params):
        rho = np.zeros(self.flow.mesh.n_elements) if rho is None else np.asarray(rho, dtype=float)
        fl = self.flow
        psi = self.weight(rho, params)
        ve, pe = fl.split(w)
        Xe = fl.corners(x)
        el, we = self.element, w[fl.dofs]
        if self.form != "reaction":                     # stress-divergence, pressure
            if el.stress_load_shape is not None:
                return el.stress_load_shape(Xe, ve, pe, self.viscosity) * psi[:, None, None]
            return corner_derivatives(lambda X: np.einsum("eab,eb->ea", load_operator(X, self.viscosity, el), we),
                                      Xe) * psi[:, None, None]
        brinkman = fl.brinkman(params)
        alpha = brinkman(rho)
        dR = fl.shape_elements(w, x, rho, params)[1][:, :self.k2]
        dmass = (el.mass_shape(Xe, ve) if el.mass_shape is not None else
                 corner_derivatives(lambda X: np.einsum("eab,eb->ea", brinkman_operator(X, el), we), Xe))
        drows = (alpha - brinkman.alpha_min - psi * alpha)[:, None, None] * dmass + psi[:, None, None] * dR
        return np.matmul(self.to_corners, self.free[..., None] * drows)

    def shape_partial(self, w, x, rho, params=None) -> sp.csr_matrix:
        """``df/dx`` (2n x 2n)."""
        if self._shape_pattern is None:
            self._shape_pattern = SparsePattern(self.dofs, self.dofs, (self.size, self.size))
        return self._shape_pattern.assemble(self.shape_elements(w, x, rho, params))

    def shape_partial_transpose(self, lam, w, x, rho, params=None) -> np.ndarray:
        """``(df/dx)^T lam`` (2n,) without assembling ``df/dx``."""
        return assemble_vector(self.dofs, np.einsum("eab,ea->eb", self.shape_elements(w, x, rho, params),
                                                    lam[self.dofs]), self.size)
