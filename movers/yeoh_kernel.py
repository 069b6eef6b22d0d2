"""Batched residual and tangent of the Yeoh mesh (total Lagrangian, Q1, 2x2 Gauss points).

Per element ``e`` and Gauss point ``g`` (weight ``w det J0``, reference shape
gradients ``dN_am`` on the unit square, ``B = dxi/dX`` the inverse of the
reference element map):

    F = I + sum_a u_a (x) dN_a B,
    R_ai = sum_g sum_m dN_am Pt_im,              Pt = w det J0 P B^T,
    K_(ai)(bk) = sum_g sum_mn dN_am At_ikmn dN_bn, At = w det J0 A_iJkL B_mJ B_nL,

with ``P`` and ``A = dP/dF`` from :func:`movers.yeoh_material.piola_and_elasticity`
(the pulled-back forms directly). Gauss-point data are stored component
first, ``(..., N)`` with ``N = E G`` points, so the material law is a few
dozen operations on contiguous arrays; the sums over Gauss points and
reference gradients are one matrix product each, with constant tables
(``dN`` for the residual, ``dN_am dN_bn`` for the tangent). One pass gives
the residual and the tangent from the same invariants.
"""

from __future__ import annotations

import numpy as np

from movers.yeoh_material import piola_and_elasticity
from tofsi.fem.geometry import jacobians
from tofsi.fem.quadrature import gauss_square
from tofsi.fem.shapes import shape_functions

BLOCK = 2048          # elements per block of the material law (8192 Gauss points)


class YeohKernel:
    """Batched residual and tangent of the Yeoh mesh on a fixed reference mesh.

    problem : the :class:`~movers.problem.MotionProblem` (its points, quads and
    stiffening); params : the mover's parameters (``A10, A20, A30, kappa``);
    stiffening : factors ``(Em,)`` instead of the problem's (may be complex).
    """

    def __init__(self, problem, params, stiffening=None):
        points, weights = gauss_square(2)
        _, dN = shape_functions(1, points)                          # (G, 4, 2)
        Xe = problem.points[problem.quads]
        _, det0, inv = jacobians(Xe, points)                        # (E, G), (E, G, 2, 2)
        E, G = det0.shape
        self.shape = (E, G)
        self.problem, self.p = problem, params
        self.pull = np.ascontiguousarray(inv.transpose(2, 3, 0, 1).reshape(2, 2, E * G))
        self.weight = (det0 * weights).reshape(-1)
        self.dN = np.ascontiguousarray(dN)
        self.dN_rows = dN.transpose(0, 2, 1).reshape(2 * G, 4)      # [(g, m), a]
        self.dN_pairs = np.einsum("gam,gbn->gmnab", dN, dN).reshape(4 * G, 16)   # [(g, m, n), (a, b)]
        factors = problem.stiffening if stiffening is None else stiffening
        self.A20 = np.repeat(params.A20 * np.asarray(factors), G)   # (N,)

    def deformation_gradient(self, x: np.ndarray) -> np.ndarray:
        """``F`` ``(2, 2, N)``, component first."""
        E, G = self.shape
        ue = x.reshape(-1, 2)[self.problem.quads]                   # (E, 4, 2)
        H = np.tensordot(ue, self.dN, axes=([1], [1]))              # (E, 2 i, G, 2 m)
        H = H.transpose(1, 3, 0, 2).reshape(2, 2, E * G)
        F = np.einsum("imn,mJn->iJn", H, self.pull)
        F[0, 0] += 1.0
        F[1, 1] += 1.0
        return F

    def evaluate(self, x: np.ndarray, tangent: bool = True):
        """Element residuals ``(E, 8)``, tangents ``(E, 8, 8)`` (or None), min det F ``(E,)``;
        residual and tangent None when an element is inverted (``det F <= 0``).

        The material law runs on blocks of :data:`BLOCK` elements, whose Gauss-point
        arrays stay in the processor's cache (2-4x faster than whole-mesh arrays)."""
        p, (E, G) = self.p, self.shape
        F = self.deformation_gradient(np.asarray(x).reshape(-1))
        detF = F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
        det_min = detF.reshape(E, G).min(axis=1)
        if np.any(det_min <= 0.0):                  # inverted: the energy is undefined there
            return None, None, det_min
        dtype = np.result_type(F, self.A20)
        Re = np.empty((E, 4, 2), dtype=dtype)
        Ke = np.empty((E, 8, 8), dtype=dtype) if tangent else None
        M = np.empty((3, min(BLOCK, E), G, 2, 2), dtype=dtype) if tangent else None
        for start in range(0, E, BLOCK):
            e = slice(start, min(start + BLOCK, E))
            n, Eb = slice(e.start * G, e.stop * G), e.stop - e.start
            # At[(i, k), m, n, (e, g)] written straight into the layout of the tangent's product
            Mb = None if M is None else M[:, :Eb]
            Pt, _ = piola_and_elasticity(F[..., n], p.A10, self.A20[n], p.A30, p.kappa, self.pull[..., n],
                                         self.weight[n], tangent,
                                         out=None if Mb is None else Mb.transpose(0, 3, 4, 1, 2).reshape(3, 2, 2, Eb * G))
            # R[e, a, i] = sum_(g, m) dN[g, a, m] Pt[i, m, (e, g)]
            Q = Pt.reshape(2, 2, Eb, G).transpose(0, 2, 3, 1).reshape(2 * Eb, 2 * G)
            Re[e] = (Q @ self.dN_rows).reshape(2, Eb, 4).transpose(1, 2, 0)
            if tangent:
                # K[e, (a, i), (b, k)] = sum_(g, m, n) At[(i, k), m, n, (e, g)] dN[g, a, m] dN[g, b, n]
                K00, K01, K11 = (Mb.reshape(3 * Eb, 4 * G) @ self.dN_pairs).reshape(3, Eb, 4, 4)
                Ke[e, 0::2, 0::2] = K00
                Ke[e, 0::2, 1::2] = K01
                Ke[e, 1::2, 0::2] = K01.transpose(0, 2, 1)
                Ke[e, 1::2, 1::2] = K11
        return Re.reshape(E, 8), Ke, det_min
