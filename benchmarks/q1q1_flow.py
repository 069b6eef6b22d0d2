"""Evaluate a design with topFlow's discretization (Q1/Q1, PSPG-stabilized) in the Stokes limit,
to separate the discretization from everything else when comparing with topFlow's numbers.

Written from the weak form stated in Alexandersen (2023), eq. for the stabilized Brinkman
problem, on a uniform grid of square-ish elements (all elements alike, so the element
matrices are computed once and scaled per element):

    momentum:   int alpha N_a u_i + mu dN_a/dx_j (du_i/dx_j + du_j/dx_i) - dN_a/dx_i p = 0
    continuity: int M_c div u + tau dM_c/dx_i (alpha u_i + dp/dx_i) = 0
    tau = (tau3^-2 + tau4^-2)^(-1/2),  tau3 = rho h^2 / (12 mu),  tau4 = rho / alpha,
    h = element diagonal,  phi = int 1/2 alpha |u|^2 + 1/2 mu du_i/dx_j (du_i/dx_j + du_j/dx_i)

Dropped against topFlow: convection and the SUPG terms (inlet Reynolds number 1/6) and the
advective time scale tau1 = h / (2 |u|) (tau3 is 1e3 times smaller in the fluid at h = 1/102);
the script prints Taylor-Hood's phi with and without convection, the size of that limit.
Boundary conditions as topFlow's double pipe: parabolic inflow, outlets with p = 0 and no
tangential velocity (strongly), walls elsewhere. Velocity and pressure live on the Q1 nodes.

    python benchmarks/q1q1_flow.py DESIGN.npy --scene examples/scenes/topflow_double_pipe.toml
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path


import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402

G = np.array([-np.sqrt(3 / 5), 0.0, np.sqrt(3 / 5)])
W = np.array([5 / 9, 8 / 9, 5 / 9])
CORNERS = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=float)


def reference_matrices(dx: float, dy: float):
    """Element integrals on a dx x dy rectangle (3 x 3 Gauss), dofs u: [u0x, u0y, ..., u3y], p: 4."""
    M = np.zeros((8, 8)); K = np.zeros((8, 8)); Gp = np.zeros((8, 4)); D = np.zeros((4, 8))
    C = np.zeros((4, 8)); L = np.zeros((4, 4))
    det = dx * dy / 4
    for xi, wx in zip(G, W):
        for eta, wy in zip(G, W):
            N = 0.25 * (1 + CORNERS[:, 0] * xi) * (1 + CORNERS[:, 1] * eta)
            dN = np.column_stack([0.25 * CORNERS[:, 0] * (1 + CORNERS[:, 1] * eta) * 2 / dx,
                                  0.25 * CORNERS[:, 1] * (1 + CORNERS[:, 0] * xi) * 2 / dy])   # (4, 2)
            w = wx * wy * det
            Nu = np.zeros((2, 8)); Nu[0, 0::2] = N; Nu[1, 1::2] = N
            B = np.zeros((2, 2, 8))               # B[i, j] . u = du_i/dx_j
            B[0, :, 0::2] = dN.T; B[1, :, 1::2] = dN.T
            M += w * Nu.T @ Nu
            for i in range(2):
                for j in range(2):
                    K += w * np.outer(B[i, j], B[i, j] + B[j, i])
            div = B[0, 0] + B[1, 1]
            Gp += w * np.outer(div, N)            # int dN_a/dx_i M_c
            D += w * np.outer(N, div)             # int M_c div u
            C += w * dN @ Nu                      # int dM_c/dx_i N_b (component i)
            L += w * dN @ dN.T
    return M, K, Gp, D, C, L


def solve_and_phi(mesh, rho_fluid_alpha, mu, inflow, outlets, density=1.0):
    """Solve the Q1/Q1 PSPG Stokes-Brinkman problem; return phi and the nodal velocity (n, 2).

    mesh: tofsi StructuredQuadMesh (uniform); rho_fluid_alpha: alpha per element;
    inflow: list of (y0, y1, peak) on the left; outlets: list of (y0, y1) on the right."""
    dx, dy = mesh.xs[1] - mesh.xs[0], mesh.ys[1] - mesh.ys[0]
    M, K, Gp, D, C, L = reference_matrices(dx, dy)
    alpha = np.asarray(rho_fluid_alpha)
    h = np.hypot(dx, dy)
    tau3 = density * h**2 / (12 * mu)
    tau4 = density / alpha
    tau = (tau3**-2 + tau4**-2) ** -0.5                                     # (E,)
    n = mesh.n_nodes
    E = mesh.n_elements
    q = mesh.quads
    udofs = (2 * q[:, :, None] + np.arange(2)).reshape(E, 8)
    dofs = np.hstack([udofs, 2 * n + q])                                    # (E, 12)
    Ke = np.zeros((E, 12, 12))
    Ke[:, :8, :8] = mu * K + alpha[:, None, None] * M
    Ke[:, :8, 8:] = -Gp
    Ke[:, 8:, :8] = D + (tau / density * alpha)[:, None, None] * C
    Ke[:, 8:, 8:] = (tau / density)[:, None, None] * L
    rows = np.broadcast_to(dofs[:, :, None], Ke.shape).ravel()
    cols = np.broadcast_to(dofs[:, None, :], Ke.shape).ravel()
    A = sp.csr_matrix((Ke.ravel(), (rows, cols)), shape=(3 * n, 3 * n))
    P = mesh.points
    left, right = mesh.side_nodes("left"), mesh.side_nodes("right")
    bottom, top = mesh.side_nodes("bottom"), mesh.side_nodes("top")
    values = np.zeros(3 * n)
    fixed = np.zeros(3 * n, dtype=bool)
    for nodes in (left, right, bottom, top):
        fixed[2 * nodes] = fixed[2 * nodes + 1] = True
    y = P[left, 1]
    for y0, y1, U in inflow:
        inside = (y > y0 + 1e-9) & (y < y1 - 1e-9)
        values[2 * left[inside]] = 4 * U * (y[inside] - y0) * (y1 - y[inside]) / (y1 - y0) ** 2
    y = P[right, 1]
    for y0, y1 in outlets:                    # p = 0 and u_y = 0 on the outlet's nodes, u_x free
        on = (y >= y0 - 1e-9) & (y <= y1 + 1e-9)
        inside = (y > y0 + 1e-9) & (y < y1 - 1e-9)
        fixed[2 * right[inside]] = False
        fixed[2 * n + right[on]] = True
    free = np.flatnonzero(~fixed)
    rhs = -A @ values
    x = values.copy()
    x[free] = spla.spsolve(A[free][:, free].tocsc(), rhs[free])
    ue = x[udofs]                                                           # (E, 8)
    phi = 0.5 * np.einsum("ea,eab,eb->e", ue, mu * K + alpha[:, None, None] * M, ue)
    return float(phi.sum()), x[:2 * n].reshape(-1, 2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("designs", nargs="*", type=Path, help="design.npy files (gamma of the scene)")
    parser.add_argument("--scene", type=Path, default=Path("examples/scenes/topflow_double_pipe.toml"))
    parser.add_argument("--set", action="append", default=[], help="scene override KEY=VALUE")
    parser.add_argument("--sharp", action="store_true", help="also the two straight pipes of the inlets")
    args = parser.parse_args()
    import tofsi
    from tofsi.interpolation import Brinkman
    scene = tofsi.load_scene(args.scene, args.set)
    p = tofsi.Problem(scene)
    stokes = tofsi.Problem(tofsi.load_scene(args.scene, args.set + ["effects.fluid=stokes"]))
    for problem in (p, stokes):                      # the last continuation step's q
        problem.set_stage(dataclasses.replace(problem.params, brinkman_q=scene.design.brinkman_q[-1]))
    mesh = p.model.mesh
    f = scene.fluid
    inflow = [(a, b, U) for a, b, U in f.left.inflow]
    outlets = [tuple(s) for s in f.right.open]
    designs = [(str(d), np.load(d)) for d in args.designs]
    if args.sharp:                            # the design region is the whole domain here
        y = mesh.centroids[p.map.design, 1]
        pipes = np.zeros(p.n_design, dtype=bool)
        for a, b, _ in inflow:
            pipes |= (y > a) & (y < b)
        designs.append(("two straight pipes", np.where(pipes, 0.0, 1.0)))
    brinkman = Brinkman(f.alpha_max, f.alpha_min, scene.design.brinkman_q[-1])
    for name, gamma in designs:
        alpha = brinkman(p.densities(gamma))
        phi_q1, _ = solve_and_phi(mesh, alpha, f.viscosity, inflow, outlets, f.density or 1.0)
        phi_th, phi_stokes = p.evaluate(gamma)[0], stokes.evaluate(gamma)[0]
        print(f"{name}: Q1/Q1 PSPG Stokes phi = {phi_q1:.4f}; Taylor-Hood {scene.effects.fluid} "
              f"{phi_th:.4f}, Stokes {phi_stokes:.4f}; Q1/Q1 / Taylor-Hood Stokes = {phi_q1 / phi_stokes:.4f}")


if __name__ == "__main__":
    main()
