"""Material interpolations of the physical density ``rho`` (1 solid, 0 fluid).

Each is a small class with the value and its derivative, so the chain rule
``d/drho`` is written once, by whoever needs it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Brinkman:
    """Brinkman friction (Borrvall-Petersson; Lundgaard et al. 2018), fluid fraction ``f = 1 - rho``:

        alpha(rho) = alpha_max - (alpha_max - alpha_min) f (1 + q) / (f + q)
                   = alpha_min + (alpha_max - alpha_min) q rho / (1 - rho + q)

    alpha(0) = alpha_min, alpha(1) = alpha_max; small ``q`` keeps alpha low
    until rho is close to 1. Units kg/(m^3 s).
    """

    alpha_max: float
    alpha_min: float = 0.0
    q: float = 0.1

    def __call__(self, rho):
        rho = np.asarray(rho)
        return self.alpha_min + (self.alpha_max - self.alpha_min) * self.q * rho / (1.0 - rho + self.q)

    def derivative(self, rho):
        rho = np.asarray(rho)
        return (self.alpha_max - self.alpha_min) * self.q * (1.0 + self.q) / (1.0 - rho + self.q) ** 2


@dataclass(frozen=True)
class SIMP:
    """Modified SIMP: ``E(rho) = Emin + rho^p (E0 - Emin)`` [Pa]. ``rho^p`` is extended oddly to
    ``rho < 0`` (``-|rho|^p``; only gradient checks step there), so a non-integer ``p`` (a
    continued penalty) stays finite and smooth there."""

    E0: float
    Emin: float
    p: float = 3.0

    def __call__(self, rho):
        rho = np.asarray(rho)
        return self.Emin + np.sign(rho) * np.abs(rho) ** self.p * (self.E0 - self.Emin)

    def derivative(self, rho):
        return self.p * np.abs(np.asarray(rho)) ** (self.p - 1.0) * (self.E0 - self.Emin)
