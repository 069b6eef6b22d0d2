"""Restarted GMRES with a right preconditioner, at the memory its preconditioner allows.

Right preconditioning, ``A M^{-1} y = b``, ``x = M^{-1} y``, minimizes the true
residual ``|b - A x|`` over the Krylov space, so the tolerance is on the residual
of the system itself. The Arnoldi basis ``V`` (``m + 1`` vectors of length ``n``)
is orthogonalized by classical Gram-Schmidt applied twice (CGS2: two
matrix-vector products with the basis per step, orthogonal to working
precision; Giraud, Langou & Rozloznik 2005), and the least-squares problem
is updated by Givens rotations. At the end of a cycle

* **GMRES(m)** (a fixed preconditioner, a linear operator ``M^{-1}``): ``x +=
  M^{-1} (V_m y)``, one more preconditioner application per cycle; the basis
  holds ``m + 1`` vectors;
* **FGMRES(m)** (Saad 1993; a preconditioner that changes from step to step,
  e.g. an inner iteration to a tolerance): ``x += Z_m y`` with the
  preconditioned vectors ``Z`` kept, ``2 m + 1`` vectors.

Measured on the flow Jacobian at 16 200 elements (``docs/parallel.md``): the
same iteration counts as pyamg's Householder FGMRES to the same tolerance,
with the basis a third of its size at ``m = 30``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import solve_triangular


def gmres(A, b: np.ndarray, apply, goal: float, max_iter: int, restart: int, x0=None,
          flexible: bool = False) -> tuple[np.ndarray, int]:
    """Solve ``A x = b`` to ``|b - A x| <= goal`` (absolute) by restarted GMRES(``restart``)
    right-preconditioned with ``apply`` (``r -> M^{-1} r``), at most ``max_iter`` iterations
    from ``x0`` (zero by default); ``flexible``: keep the preconditioned vectors (FGMRES), for
    a preconditioner that is not one fixed linear operator. Returns ``(x, iterations)``; the
    caller checks the residual (the last cycle's estimate may be optimistic)."""
    n = b.shape[0]
    dtype = np.result_type(A.dtype, b.dtype)
    x = np.zeros(n, dtype=dtype) if x0 is None else np.array(x0, dtype=dtype)
    r = b - A @ x if x0 is not None else np.array(b, dtype=dtype)
    beta = float(np.linalg.norm(r))
    m = max(1, min(restart, max_iter))
    V = np.empty((m + 1, n), dtype=dtype)
    Z = np.empty((m, n), dtype=dtype) if flexible else None
    H = np.zeros((m + 1, m))
    iterations = 0
    while beta > goal and iterations < max_iter and math.isfinite(beta):
        V[0] = r / beta
        del r
        g = np.zeros(m + 1)
        g[0] = beta
        cs, sn = np.zeros(m), np.zeros(m)
        H[:] = 0.0
        k = 0
        while k < m and iterations < max_iter:
            z = apply(V[k])
            if flexible:
                Z[k] = z
            w = A @ z
            del z
            basis = V[:k + 1]
            h = basis @ w                                  # classical Gram-Schmidt, twice
            w -= h @ basis
            h2 = basis @ w
            w -= h2 @ basis
            h += h2
            norm = float(np.linalg.norm(w))
            H[:k + 1, k] = h
            H[k + 1, k] = norm
            if norm > 0.0:
                V[k + 1] = w / norm
            del w
            for i in range(k):                             # the earlier rotations
                H[i, k], H[i + 1, k] = (cs[i] * H[i, k] + sn[i] * H[i + 1, k],
                                        -sn[i] * H[i, k] + cs[i] * H[i + 1, k])
            rho = math.hypot(H[k, k], H[k + 1, k])
            cs[k], sn[k] = (1.0, 0.0) if rho == 0.0 else (H[k, k] / rho, H[k + 1, k] / rho)
            H[k, k], H[k + 1, k] = rho, 0.0
            g[k + 1] = -sn[k] * g[k]
            g[k] = cs[k] * g[k]
            k += 1
            iterations += 1
            if abs(g[k]) <= goal or norm == 0.0:
                break
        y = solve_triangular(H[:k, :k], g[:k], check_finite=False)
        x += (y @ Z[:k]) if flexible else apply(y @ V[:k])
        r = b - A @ x
        beta = float(np.linalg.norm(r))
    return x, iterations
