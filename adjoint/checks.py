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


def _scalar_taylor(f, z, slope, direction, eps0=1e-2, steps=5):
    """Remainders ``|f(z + eps d) - f(z) - eps slope|`` and their rates."""
    f0 = f(z)
    eps = [eps0 / 2**k for k in range(steps)]
    rem = [abs(f(z + e * direction) - f0 - e * slope) for e in eps]
    rates = [float(np.log2(rem[k] / rem[k + 1])) if rem[k + 1] > 0 else np.inf for k in range(steps - 1)]
    return eps, rem, rates


def check_row(name, eps, rem, rates, cd_error, scale, cd_tol):
    """One table row: passes when the rate is 2 (or the remainder is round-off: a linear map)."""
    linear = max(rem) <= 1e-9 * max(scale, 1e-300) * eps[0]
    ok = (linear or min(rates) > 1.9) and cd_error < cd_tol
    return {"check": name, "min_rate": float(min(rates)), "max_remainder": float(max(rem)),
            "linear": bool(linear), "cd_error": float(cd_error), "passed": bool(ok)}


def _direction(rng, z, floor):
    """A random direction scaled to the field: 1 % of its largest entry (at least ``floor``)."""
    return rng.normal(size=z.size) * max(1e-2 * float(np.abs(z).max()), floor)


def check_blocks(system, state, seed: int = 0, cd_tol: float = 1e-6) -> list[dict]:
    """Every block's derivatives at ``state`` against Taylor tests and central differences.

    For block ``b`` and a random multiplier ``lam`` the scalar ``phi = lam . R_b`` is
    differentiated along random directions in the block's own field (Dirichlet dofs
    held), in each input field and in the densities; the claimed slopes come from the
    block's linearization -- ``(dR_b/dz_b)^T lam``, and ``transpose_partials(lam)`` --
    so every transposed product the adjoint uses is checked. Rows are named
    ``<residual>_<field>`` (``F_w``, ``S_rho``, ``D_u``, ...).
    """
    rng = np.random.default_rng(seed)
    rho, params = state.rho, state.params
    rows = []
    h = 1e-4                   # times directions of 1 % of the field: steps of 1e-6 of it
    for block in system.blocks:
        lin = state.linearizations[block.name]
        if block.has_residual:
            lin = block.linearize(state.fields, rho, params)

        def phi(fields=None, rho_=None, lam=None, block=block):
            values = dict(state.fields) if fields is None else fields
            return float(lam @ block.residual(values, rho if rho_ is None else rho_, params))

        lam = rng.normal(size=block.size)
        inputs, rho_bar = lin.transpose_partials(lam)
        own = block.homogenize(_direction(rng, state.fields[block.name], 1e-6))
        candidates = [(block.name, own, lin.matrix().T @ lam)]
        candidates += [(o, _direction(rng, state.fields[o], 1e-6), inputs.get(o, np.zeros(state.fields[o].size)))
                       for o in block.inputs]
        for field, d, grad in candidates:
            def f(z, field=field, lam=lam):
                return phi({**state.fields, field: z}, lam=lam)
            z = state.fields[field]
            slope = float(grad @ d)
            eps, rem, rates = _scalar_taylor(f, z, slope, d)
            cd = (f(z + h * d) - f(z - h * d)) / (2 * h)
            rows.append(check_row(f"{block.symbol or block.name}_{field}", eps, rem, rates, relative_error(cd, slope),
                                  abs(slope), cd_tol))
        if rho_bar is not None or block.has_residual:
            # steps that keep densities inside (0, 1) (scaled by 4 rho (1 - rho): the fixed 0/1
            # elements stay, where interpolations may end in a pole or a kink -- a Brinkman q of
            # 5e-6 puts alpha's pole at rho = 1 + q, a SIMP exponent between 1 and 2 a kink at 0)
            noise = rng.normal(size=rho.size)
            d = 0.01 * noise * 4.0 * rho * (1.0 - rho)
            if not np.any(d):                                 # a 0/1 design: small steps anyway
                d = 0.01 * noise
            slope = float((np.zeros(rho.size) if rho_bar is None else rho_bar) @ d)
            g = lambda r, lam=lam: phi(rho_=r, lam=lam)
            eps, rem, rates = _scalar_taylor(g, rho, slope, d)
            cd = (g(rho + h * d) - g(rho - h * d)) / (2 * h)
            rows.append(check_row(f"{block.symbol or block.name}_rho", eps, rem, rates, relative_error(cd, slope),
                                  abs(slope), cd_tol))
    return rows


def check_totals(problem, gamma, seed: int = 0, cd_tol: float = 1e-5, eps0: float = 1e-2) -> list[dict]:
    """The objective's and the constraint's total derivatives (Taylor test from steps ``eps0``,
    central differences)."""
    rng = np.random.default_rng(seed)
    rows = []
    quantities = [("objective " + problem.objective.name, lambda g: problem.evaluate(g))]
    quantities += [(f"constraint {name}", lambda g, i=i: tuple(a[i] for a in problem.constraints(g)))
                   for i, name in enumerate(problem.constraint_names())]
    for name, fun in quantities:
        f0, grad = fun(gamma)
        d = rng.normal(size=gamma.size)
        value = lambda g, fun=fun: fun(g)[0]
        t = taylor_test(value, gamma, grad, d, eps0=eps0, steps=5, f0=f0)
        cd = central_difference(value, gamma, d, 1e-5)
        rows.append(check_row(name, t.eps, t.remainders, t.rates, relative_error(cd, grad @ d),
                              abs(grad @ d), cd_tol))
    return rows
