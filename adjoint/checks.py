"""Gradient checks: the Taylor test and central differences (pyadjoint's ``taylor_test`` idea).

For a scalar ``f`` with claimed gradient ``g`` at ``x`` and a direction ``d``,
the remainders ``r(eps) = |f(x + eps d) - f(x) - eps g . d|`` fall as
``eps^2`` when ``g`` is right and as ``eps`` when a term is missing; the
rates ``log2(r(eps) / r(eps/2))`` for ``eps = eps0 / 2^k`` show which.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


@dataclass
class TaylorResult:
    eps: list
    remainders: list
    rates: list
    min_rate: float

    def as_dict(self) -> dict:
        return asdict(self)


def taylor_test(f, x: np.ndarray, gradient: np.ndarray, direction: np.ndarray,
                eps0: float = 1e-2, steps: int = 5, f0: float | None = None) -> TaylorResult:
    """Remainders and rates of the first-order Taylor expansion along ``direction``."""
    f0 = f(x) if f0 is None else f0
    slope = float(np.dot(gradient, direction))
    eps = [eps0 / 2**k for k in range(steps)]
    rem = [abs(f(x + e * direction) - f0 - e * slope) for e in eps]
    rates = [float(np.log2(rem[k] / rem[k + 1])) if rem[k + 1] > 0 else np.inf for k in range(steps - 1)]
    return TaylorResult(eps, rem, rates, float(min(rates)))


def central_difference(f, x: np.ndarray, direction: np.ndarray, h: float) -> float:
    """``(f(x + h d) - f(x - h d)) / 2h``."""
    return (f(x + h * direction) - f(x - h * direction)) / (2 * h)


def relative_error(a: float, b: float, floor: float = 1e-300) -> float:
    return abs(a - b) / max(abs(a), abs(b), floor)


def _vector_taylor(R, z, Jd, direction, eps0=1e-2, steps=5):
    """Remainders ``|R(z + eps d) - R(z) - eps J d|`` and their rates (vector residuals)."""
    R0 = R(z)
    eps = [eps0 / 2**k for k in range(steps)]
    rem = [float(np.linalg.norm(R(z + e * direction) - R0 - e * Jd)) for e in eps]
    rates = [float(np.log2(rem[k] / rem[k + 1])) if rem[k + 1] > 0 else np.inf for k in range(steps - 1)]
    return eps, rem, rates


def check_row(name, eps, rem, rates, cd_error, scale, cd_tol):
    """One table row: passes when the rate is 2 (or the remainder is round-off: a linear map)."""
    linear = max(rem) <= 1e-9 * max(scale, 1e-300) * eps[0]
    ok = (linear or min(rates) > 1.9) and cd_error < cd_tol
    return {"check": name, "min_rate": float(min(rates)), "max_remainder": float(max(rem)),
            "linear": bool(linear), "cd_error": float(cd_error), "passed": bool(ok)}


def check_blocks(model, state, seed: int = 0, cd_tol: float = 1e-6) -> list[dict]:
    """Every Jacobian block of the scene's residuals against Taylor tests and central differences."""
    from adjoint.blocks import Blocks
    rng = np.random.default_rng(seed)
    b = Blocks(model, state)
    X = state.displacement
    rows = []
    fl, st, rho = model.flow, model.structure, state.rho
    x = np.zeros(2 * model.mesh.n_nodes) if state.x is None else state.x
    u, w = state.u, state.w
    h = 1e-6

    def add(name, R, z, J, scale_z):
        d = rng.normal(size=z.size) * scale_z
        Jd = J @ d
        eps, rem, rates = _vector_taylor(R, z, Jd, d)
        cd = (R(z + h * d) - R(z - h * d)) / (2 * h)
        err = np.linalg.norm(cd - Jd) / max(np.linalg.norm(cd), np.linalg.norm(Jd), 1e-300)
        rows.append(check_row(name, eps, rem, rates, err, np.linalg.norm(Jd), cd_tol))

    wscale = max(np.abs(w).max(), 1e-3)
    F = lambda w_, x_=x, r_=rho: fl.bc.free_rows_vector(fl.residual(w_, x_.reshape(-1, 2), r_))
    from tofsi.fem.assembly import SparsePattern
    _, _, Ke = fl.jacobian(w, X, rho)
    Fw_full = fl.bc.free_rows(SparsePattern(fl.dofs, fl.dofs, (fl.size, fl.size)).assemble(Ke))
    add("F_w", F, w, Fw_full, wscale)
    add("F_rho", lambda r: F(w, x, r), rho, b.F_rho(), 0.05)
    if model.two_way:
        add("F_x", lambda x_: F(w, x_), x, b.F_x(), 1e-3)
    if st is not None:
        S = lambda u_=u, w_=w, x_=x, r_=rho: st.bc.free_rows_vector(st.residual(u_, w_, x_.reshape(-1, 2), r_))
        K = st.bc.free_rows(SparsePattern(st.dofs, st.dofs, (st.size, st.size)).assemble(st.element_matrices(rho)))
        uscale = max(np.abs(u).max(), 1e-9)
        add("S_u", lambda u_: S(u_), u, K, uscale)
        add("S_w", lambda w_: S(w_=w_), w, b.S_w(), wscale)
        add("S_rho", lambda r: S(r_=r), rho, b.S_rho(), 0.05)
        if model.two_way:
            add("S_x", lambda x_: S(x_=x_), x, b.S_x(), 1e-3)
    if model.two_way and model.motion.has_residual:
        m = model.motion
        D = lambda x_=x, u_=u, r_=rho: m.residual(x_, u_, r_)[0]
        add("D_x", lambda x_: D(x_), x, m.residual(x, u, rho)[1], 1e-3)
        add("D_u", lambda u_: D(u_=u_), u, m.structure_partial(rho), 1e-3)
    return rows


def check_totals(problem, gamma, seed: int = 0, cd_tol: float = 1e-5) -> list[dict]:
    """The objective's and the constraint's total derivatives (Taylor test, central differences)."""
    rng = np.random.default_rng(seed)
    rows = []
    for name, fun in (("objective " + problem.objective.name, lambda g: problem.evaluate(g)),
                      ("constraint volume", lambda g: tuple(a[0] for a in problem.constraints(g)))):
        f0, grad = fun(gamma)
        d = rng.normal(size=gamma.size)
        value = lambda g, fun=fun: fun(g)[0]
        t = taylor_test(value, gamma, grad, d, eps0=1e-2, steps=5, f0=f0)
        cd = central_difference(value, gamma, d, 1e-5)
        rows.append(check_row(name, t.eps, t.remainders, t.rates, relative_error(cd, grad @ d),
                              abs(grad @ d), cd_tol))
    return rows
