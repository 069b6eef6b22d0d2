"""Krylov variants of the adjoint's transposed flow solve, on the systems of ``benchmarks/optimize.py``.

Every transposed GMRES call of a ``benchmarks/optimize.py`` run (one-way 180 x 90 beam,
iterative backend) is intercepted: the shipped GMRES(30) answers it (the optimization's
path is unchanged), and beside it, on the same right-preconditioned operator
``K = (D^{-1/2} J^T D^{-1/2}) M^{-1}`` and right-hand side ``b``, with ``M^{-1}`` the
scaled ``P^{-T}`` (``tofsi.linalg.iterative``), to the same residual ``|b - K t| <= goal``:

* **GCRO-DR(m + k, k)** recycling across designs (Parks, de Sturler, Mackey, Johnson &
  Maiti 2006; Wang, de Sturler & Paulino 2007): the ``k`` harmonic Ritz vectors ``U``
  of smallest ``|theta|`` kept from the previous design's solve, ``C = K U`` rebuilt at
  the new design (``k`` applications of ``K``, counted), ``C = Q R``, ``U <- U R^{-1}``,
  ``t_0 = U C^T b``; then cycles of ``m`` Arnoldi steps with ``(I - C C^T) K``,
  ``K [U V_m] = [C V_{m+1}] G``, ``G = [[I, B], [0, H]]``, the update
  ``t += V y - U B y`` with ``y = argmin |beta e_1 - H y|``, and after each cycle the
  new ``U`` from ``G^T G z = theta G^T [C V_{m+1}]^T [U V_m] z``;
* **left preconditioning**: GMRES(m) on ``M^{-1} K' x = M^{-1} b`` (``K'`` the scaled
  ``J^T``: the transpose of the forward right-preconditioned operator ``J P^{-1}``),
  stopped on the true residual ``|b - K' x| <= goal`` (evaluated every iteration);
* the shipped GMRES(m)'s residual history: iterations to 5, 3, 2, 1, 0.5, 0.1 and
  0.01 times the tolerance.

    python -m benchmarks.transposed_variants [--recycle 5 10 20] [optimize.py's options]

prints one JSON line per transposed solve (``k``: applications of ``K`` and iterations).
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np
from scipy.linalg import eig, lstsq, qr, solve_triangular


def arnoldi_step(K, V: np.ndarray, j: int, C: np.ndarray | None = None):
    """``w = (I - V V^T)(I - C C^T) K v_j`` by classical Gram-Schmidt twice: ``(w, h, C^T K v_j)``."""
    w = K(V[:, j])
    b = None
    if C is not None:
        b = C.T @ w
        w -= C @ b
        b2 = C.T @ w
        w -= C @ b2
        b += b2
    h = V[:, :j + 1].T @ w
    w -= V[:, :j + 1] @ h
    h2 = V[:, :j + 1].T @ w
    w -= V[:, :j + 1] @ h2
    return w, h + h2, b


def harmonic_ritz(G: np.ndarray, projected: np.ndarray, k: int) -> np.ndarray:
    """Orthonormal coefficients (columns) of the ``k`` harmonic Ritz vectors of smallest ``|theta|``,
    ``G^T G z = theta G^T projected z`` (real and imaginary parts of a complex pair)."""
    values, vectors = eig(G.T @ G, G.T @ projected)
    columns = []
    for i in np.argsort(np.abs(values)):
        if np.isfinite(values[i]) and len(columns) < k:
            z = vectors[:, i]
            columns.append(z.real)
            if np.abs(z.imag).max() > 1e-12 * np.abs(z).max():
                columns.append(z.imag)
    return qr(np.column_stack(columns[:k]), mode="economic")[0]


def gcro_dr(K, b: np.ndarray, goal: float, m: int, k: int, U: np.ndarray | None, max_iter: int = 400):
    """GCRO-DR on ``K t = b`` from ``t = 0`` with the recycled ``U`` (or None):
    ``(t, applications of K, Arnoldi iterations, U for the next system)``."""
    t, r = np.zeros_like(b), b.copy()
    applications = iterations = 0
    C = None
    if U is not None:
        C, R = qr(np.column_stack([K(u.copy()) for u in U.T]), mode="economic")
        applications += U.shape[1]
        U = solve_triangular(R.T, U.T, lower=True).T
        c = C.T @ r
        t += U @ c
        r -= C @ c
    beta = float(np.linalg.norm(r))
    while beta > goal and iterations < max_iter:
        kept = 0 if C is None else C.shape[1]
        steps = m - kept
        V, H, Bm = np.zeros((b.size, steps + 1)), np.zeros((steps + 1, steps)), np.zeros((kept, steps))
        V[:, 0] = r / beta
        j = 0
        while j < steps:
            w, h, bc = arnoldi_step(K, V, j, C)
            applications += 1
            iterations += 1
            H[:j + 1, j], H[j + 1, j] = h, np.linalg.norm(w)
            V[:, j + 1] = w / H[j + 1, j]
            if bc is not None:
                Bm[:, j] = bc
            j += 1
            e = np.zeros(j + 1)
            e[0] = beta
            y = lstsq(H[:j + 1, :j], e)[0]
            if np.linalg.norm(e - H[:j + 1, :j] @ y) <= goal:
                break
        Hj, Vj = H[:j + 1, :j], V[:, :j + 1]
        t += Vj[:, :j] @ y
        if C is not None:
            t -= U @ (Bm[:, :j] @ y)
        r = r - Vj @ (Hj @ y)
        beta = float(np.linalg.norm(r))
        if C is None:
            G, W, Wt = Hj, Vj[:, :j], Vj
            projected = np.eye(j + 1, j)
        else:
            G = np.block([[np.eye(kept), Bm[:, :j]], [np.zeros((j + 1, kept)), Hj]])
            W, Wt = np.column_stack([U, Vj[:, :j]]), np.column_stack([C, Vj])
            projected = Wt.T @ W
        if G.shape[1] >= k:
            P = harmonic_ritz(G, projected, k)
            C, R = qr(Wt @ (G @ P), mode="economic")
            U = solve_triangular(R.T, (W @ P).T, lower=True).T
    return t, applications, iterations, U


def residual_history(K, b: np.ndarray, goal: float, m: int, max_iter: int = 400, true_residual=None) -> list:
    """GMRES(m) on ``K t = b``: the residual estimate after each iteration, or with
    ``true_residual`` (``t -> |b' - K' t|``) that of the iterate."""
    t, r = np.zeros_like(b), b.copy()
    beta, history = float(np.linalg.norm(r)), []
    while len(history) < max_iter:
        V, H = np.zeros((b.size, m + 1)), np.zeros((m + 1, m))
        V[:, 0] = r / beta
        for j in range(m):
            w, h, _ = arnoldi_step(K, V, j)
            H[:j + 1, j], H[j + 1, j] = h, np.linalg.norm(w)
            V[:, j + 1] = w / H[j + 1, j]
            e = np.zeros(j + 2)
            e[0] = beta
            y = lstsq(H[:j + 2, :j + 1], e)[0]
            history.append(float(np.linalg.norm(e - H[:j + 2, :j + 1] @ y)) if true_residual is None
                           else true_residual(t + V[:, :j + 1] @ y))
            if history[-1] <= goal:
                return history
        t += V[:, :m] @ y
        r = b - K(t)
        beta = float(np.linalg.norm(r))
    return history


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recycle", type=int, nargs="*", default=[5, 10, 20], help="numbers k of recycled vectors")
    args, rest = parser.parse_known_args()
    import tofsi.linalg.iterative as iterative
    from benchmarks import optimize

    shipped = iterative.gmres
    recycled: dict[int, np.ndarray | None] = {}

    def intercepted(A, b, apply, goal, max_iter, restart, x0=None, flexible=False):
        x, its = shipped(A, b, apply, goal, max_iter, restart, x0, flexible)
        K = lambda v: A @ apply(v)                                   # noqa: E731
        history = residual_history(K, b, 1e-2 * goal, restart)
        row = {"shipped_iterations": its, "relative_tolerance": goal / float(np.linalg.norm(b)),
               "iterations_to_times_the_tolerance": {f"{f:g}": next((i + 1 for i, h in enumerate(history)
                                                                     if h <= f * goal), None)
                                                     for f in (5, 3, 2, 1, 0.5, 0.1, 0.01)}}
        for k in args.recycle:
            t, applications, iterations, recycled[k] = gcro_dr(K, b, goal, restart + k, k, recycled.get(k))
            row[f"gcro_dr_k{k}"] = {"applications": applications, "iterations": iterations,
                                    "relative_residual": float(np.linalg.norm(b - A @ apply(t)) / np.linalg.norm(b))}
        left = residual_history(lambda v: apply(A @ v), apply(b), goal, restart,
                                true_residual=lambda y: float(np.linalg.norm(b - A @ y)))
        row["left_preconditioned_iterations"] = len(left) if left[-1] <= goal else None
        print("transposed solve", json.dumps(row), flush=True)
        return x, its

    iterative.gmres = intercepted
    sys.argv = [sys.argv[0], "--backend", "iterative", *rest]
    optimize.main()


if __name__ == "__main__":
    main()
