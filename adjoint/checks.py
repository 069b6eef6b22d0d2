"""Gradient checks: the Taylor test and central differences (pyadjoint's ``taylor_test`` idea).

For a scalar ``f`` with claimed gradient ``g`` at ``x`` and a direction ``d``,
the remainders ``r(eps) = |f(x + eps d) - f(x) - eps g . d|`` fall as
``eps^2`` when ``g`` is right and as ``eps`` when a term is missing; the
rates ``log2(r(eps) / r(eps/2))`` for ``eps = eps0 / 2^k`` show which.

That holds only while ``r`` is above the round-off of evaluating ``f``: below
it the remainder stops falling and any rate comes out (the shape blocks of a
two-way state reach it within four halvings of a 1 % step). :func:`taylor_check`
therefore measures that floor first (:func:`round_off_floor`: the scatter of
``f`` about a quadratic through five steps too small to show anything else),
chooses the steps from the remainder's size -- a first step whose remainder is
``MARGIN`` times the floor (larger steps if ``eps0``'s is not), then halvings
while the remainder stays that far above it -- and reads the rate at the
smallest such steps (the nonlinear range lies at the large ones). A remainder
at round-off at every step is a linear map when it is also negligible against
the slope; otherwise the check is *inconclusive*, never a failure.
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
    rates = [float(np.log2(rem[k] / rem[k + 1])) if rem[k] > 0 and rem[k + 1] > 0 else np.inf
             for k in range(steps - 1)]              # a remainder of exactly 0: round-off of a linear map
    return TaylorResult(eps, rem, rates, float(min(rates)))


MARGIN = 100.0           # a clean remainder is this far above the round-off floor (its rate within 0.03)
PASS_RATE = 1.9          # the Taylor rate of a right gradient (2 in exact arithmetic)
GROWTH = 4.0             # the first step grows by this factor while its remainder is at round-off ...
MAX_GROWTH = 256.0       # ... up to this many times eps0
LINEAR = 1e-9            # a remainder below LINEAR |slope| eps at the largest step: a linear map


def round_off_floor(f, z, direction, f0: float, step: float) -> float:
    """The round-off of ``f`` along ``direction``: twice the largest deviation of ``f(z + t d)``,
    ``t = step * (-1, -3/4, ..., 1)`` (nine points), from the least-squares quadratic through
    them (the quadratic takes up the slope, a wrong one too, and the curvature; ``step`` is small
    enough that the cubic term is below round-off, large enough that ``z + t d`` differs from
    ``z``). Measured on the blocks of a two-way state: within a factor 2 of the scatter of the
    remainders at steps of 1e-9 to 1e-6 (five points underestimated it up to six times)."""
    t = step * np.linspace(-1.0, 1.0, 9)
    values = np.array([f0 if ti == 0 else f(z + ti * direction) for ti in t])
    fit = np.polyval(np.polyfit(t / step, values - f0, 2), t / step)
    return float(2.0 * np.max(np.abs(values - f0 - fit)))


@dataclass
class TaylorCheck:
    """The outcome of :func:`taylor_check`: the steps and remainders measured (largest step
    first), the rates between consecutive clean ones, the rate read (at the smallest clean
    steps; NaN when there is none), the round-off floor, and ``result``: ``"ok"``, ``"linear map"``
    (remainders at round-off, negligible against the slope), ``"FAILED"`` or ``"inconclusive"``
    (no two steps with the remainder ``MARGIN`` times above the floor)."""

    eps: list
    remainders: list
    rates: list
    rate: float
    floor: float
    result: str


def taylor_check(f, z, slope: float, direction, eps0: float = 1e-2, steps: int = 6,
                 f0: float | None = None, max_growth: float = MAX_GROWTH) -> TaylorCheck:
    """A Taylor test whose steps are chosen from the remainder's size (see the module
    docstring): the first step is ``eps0``, grown by ``GROWTH`` (up to ``max_growth`` times)
    while its remainder is below ``16 MARGIN`` times the round-off floor (so two halvings stay
    clean); then at most ``steps`` steps, halving while the remainder stays clean."""
    f0 = f(z) if f0 is None else f0
    floor = round_off_floor(f, z, direction, f0, 1e-4 * eps0)

    def remainder(e):
        return abs(f(z + e * direction) - f0 - e * slope)

    def clean(r):
        return r > 0 and r >= MARGIN * floor

    def verdict(eps, rem, rates, rate, result):
        return TaylorCheck(eps, rem, rates, rate, floor, result)
    eps, rem = [eps0], [remainder(eps0)]
    while rem[0] < 16 * MARGIN * floor and eps[0] * GROWTH <= max_growth * eps0 * (1 + 1e-12):
        eps.insert(0, eps[0] * GROWTH)
        rem.insert(0, remainder(eps[0]))
    if rem[0] <= LINEAR * abs(slope) * eps[0]:          # negligible against the slope: linear
        return verdict(eps, rem, [], float("nan"), "linear map")
    eps, rem = eps[:1], rem[:1]                         # the largest step tried: the first clean one
    while len(eps) < steps and clean(rem[-1]):
        eps.append(eps[-1] / 2)
        rem.append(remainder(eps[-1]))
    rates = [float(np.log2(rem[k] / rem[k + 1])) for k in range(len(rem) - 1) if clean(rem[k]) and clean(rem[k + 1])]
    if not rates:                                       # round-off at (nearly) every step
        return verdict(eps, rem, [], float("nan"), "inconclusive")
    rate = min(rates[-2:])                              # at the smallest clean steps
    return verdict(eps, rem, rates, rate, "ok" if rate > PASS_RATE else "FAILED")


def central_difference(f, x: np.ndarray, direction: np.ndarray, h: float) -> float:
    """``(f(x + h d) - f(x - h d)) / 2h``."""
    return (f(x + h * direction) - f(x - h * direction)) / (2 * h)


def relative_error(a: float, b: float, floor: float = 1e-300) -> float:
    return abs(a - b) / max(abs(a), abs(b), floor)


def check_row(name, taylor: TaylorCheck, cd: float, slope: float, h: float, cd_tol: float) -> dict:
    """One table row: the Taylor check's verdict with the central differences' (step ``h``):
    their relative error below ``cd_tol`` is ok; above it but within three times what the
    round-off floor allows them (``floor / (h |slope|)``) inconclusive; else FAILED. ``passed``:
    the row is no failure (``result`` says whether it is ok, linear or inconclusive)."""
    cd_error = relative_error(cd, slope)
    cd_round_off = taylor.floor / max(h * abs(slope), 1e-300)
    cd_result = "ok" if cd_error < cd_tol else ("inconclusive" if cd_error < 3 * cd_round_off else "FAILED")
    results = (taylor.result, cd_result)
    result = ("FAILED" if "FAILED" in results else "inconclusive" if "inconclusive" in results
              else taylor.result)
    return {"check": name, "result": result, "passed": result != "FAILED", "min_rate": taylor.rate,
            "rates": taylor.rates, "eps": taylor.eps, "remainders": taylor.remainders,
            "max_remainder": float(max(taylor.remainders)), "round_off_floor": taylor.floor,
            "linear": taylor.result == "linear map", "cd_error": float(cd_error),
            "cd_round_off": float(cd_round_off)}


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
            taylor = taylor_check(f, z, slope, d)
            cd = (f(z + h * d) - f(z - h * d)) / (2 * h)
            rows.append(check_row(f"{block.symbol or block.name}_{field}", taylor, cd, slope, h, cd_tol))
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
            taylor = taylor_check(g, rho, slope, d, max_growth=1.0)      # densities stay in (0, 1)
            cd = (g(rho + h * d) - g(rho - h * d)) / (2 * h)
            rows.append(check_row(f"{block.symbol or block.name}_rho", taylor, cd, slope, h, cd_tol))
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
        slope = float(grad @ d)
        taylor = taylor_check(value, gamma, slope, d, eps0=eps0, steps=5, f0=f0, max_growth=1.0)
        cd = central_difference(value, gamma, d, 1e-5)
        rows.append(check_row(name, taylor, cd, slope, 1e-5, cd_tol))
    return rows
