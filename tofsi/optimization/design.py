"""Design maps: design variables gamma -> filtered -> projected -> element densities rho.

Each map is a small class with ``forward`` and ``transpose`` (the
vector-Jacobian product), so the chain rule is written once, in
:class:`DesignMap`, where it can be read:

    rho_t = H gamma / Hs                 density filter, H_ij = max(0, r - |c_i - c_j|)
                                         (or TOFLUX's circular sqrt(1 - |c_i - c_j|^2 / r^2))
    rho_p = (tanh(b e) + tanh(b (rho_t - e))) / (tanh(b e) + tanh(b (1 - e)))
    rho   = rho_p in the design region, 1 in fixed solid, 0 in fixed fluid

(Bruns & Tortorelli 2001; Wang, Lazarov & Sigmund 2011). By default the filter averages
over the design elements only; with ``design.filter_fixed`` (TOFLUX's) it also averages the
fixed elements within its radius at their values (1 solid, 0 fluid), ``rho_t = (H gamma + b)
/ Hs`` with the constant ``b``, so the design next to a fixed solid starts partly solid.

``H`` is never stored: at a fixed physical radius it holds ``pi (r/h)^2`` entries per element
(1.6 GB at 2.6e5 elements, 26 GB at 1e6). On the structured grid the weight of element
``(i + a, j + b)`` seen from ``(i, j)`` depends on the centres' offsets
``(xc[i+a] - xc[i], yc[j+b] - yc[j])`` alone, so ``H u`` is a correlation of the element
field with a stencil over the offsets ``|a| <= A, |b| <= B`` that reach ``r``:
:class:`DensityFilter` applies it offset by offset (graded axes: each offset's weights
computed from the axes as it is applied), or, on uniform axes with many offsets, as one
FFT convolution (``O(E log E)``, equal to the sums to round-off). ``H`` is symmetric
(``w(c_i, c_j) = w(c_j, c_i)``), so ``H^T`` is the same correlation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft as sp_fft

from tofsi.mesh.structured import DESIGN, SOLID


KERNELS = ("linear", "circular")
FFT_MIN_OFFSETS = 64      # a uniform grid's stencil with more offsets is applied by FFT


def filter_weights(distance: np.ndarray, radius: float, kernel: str) -> np.ndarray:
    """Filter weights at ``distance``: ``max(0, r - d)`` (linear hat) or ``sqrt(1 - d^2/r^2)``
    (circular, TOFLUX's), zero beyond ``r``."""
    if kernel == "circular":
        return np.sqrt(np.maximum(0.0, 1.0 - (distance / radius) ** 2))
    return np.maximum(0.0, radius - distance)


def uniform_spacing(centres: np.ndarray) -> float | None:
    """The spacing of equally spaced ``centres`` (to the round-off of their coordinates), else None."""
    if centres.size < 2:
        return 1.0
    d = np.diff(centres)
    h = float(d.mean())
    return h if np.max(np.abs(d - h)) <= 64 * np.finfo(float).eps * np.max(np.abs(centres)) else None


def reach(centres: np.ndarray, radius: float) -> int:
    """The largest index offset between two of the sorted ``centres`` within ``radius``."""
    return int(np.max(np.searchsorted(centres, centres + radius, side="right") - 1 - np.arange(centres.size)))


class DensityFilter:
    """The density filter of radius ``r`` [m] over the ``design`` elements of a structured
    mesh, applied as a stencil (module docstring); ``filter_fixed``: the other elements
    within ``r`` are averaged in at ``fixed_values`` ((E,): 1 solid, 0 fluid).

    Stores ``O(E)``: ``Hs`` and ``b`` per design element and, on the FFT path, the kernel's
    transform (:attr:`nbytes`). ``method``: ``"stencil"`` or ``"fft"`` (uniform axes only);
    default the FFT on uniform axes with more than :data:`FFT_MIN_OFFSETS` offsets.
    """

    def __init__(self, mesh, design: np.ndarray, radius: float, kernel: str = "linear",
                 fixed_values: np.ndarray | None = None, method: str | None = None):
        if kernel not in KERNELS:
            raise ValueError(f"filter kernel {kernel!r}: allowed {KERNELS}")
        self.radius, self.kernel = float(radius), kernel
        self.shape = (mesh.ny, mesh.nx)
        centres = mesh.centroids
        self.xc = centres[:mesh.nx, 0].copy()               # the centres' columns and rows (the same
        self.yc = centres[::mesh.nx, 1].copy()              # in every row / column of a tensor grid)
        self.reach = (reach(self.xc, radius), reach(self.yc, radius))        # (A, B)
        self.design = np.asarray(design)
        hx, hy = uniform_spacing(self.xc), uniform_spacing(self.yc)
        offsets = (2 * self.reach[0] + 1) * (2 * self.reach[1] + 1)
        if method is None:
            method = "fft" if hx is not None and hy is not None and offsets > FFT_MIN_OFFSETS else "stencil"
        if method not in ("fft", "stencil") or (method == "fft" and (hx is None or hy is None)):
            raise ValueError(f"filter method {method!r}: 'stencil', or 'fft' on uniform axes")
        self.method = method
        self._kernel_fft = None
        if method == "fft":
            self._prepare_fft(hx, hy)
        mask = np.zeros(mesh.n_elements)
        mask[self.design] = 1.0
        if fixed_values is None:
            self.Hs = self._apply(mask)
            self.b = np.zeros(self.design.size)
        else:                                                # every element within r counts in Hs
            self.Hs = self._apply(np.ones(mesh.n_elements))
            self.b = self._apply(np.where(mask > 0, 0.0, np.asarray(fixed_values, dtype=float)))

    @property
    def nbytes(self) -> int:
        """Bytes the filter holds (it stores no matrix)."""
        held = [self.Hs, self.b, self.xc, self.yc, self.design]
        if self._kernel_fft is not None:
            held.append(self._kernel_fft)
        return int(sum(a.nbytes for a in held))

    # ---- the correlation H u on the whole grid, read at the design elements ------------
    def _offset_weights(self, a: int, b: int):
        """Weights ``(rows, cols)`` of offset ``(a, b)`` over the elements that have that
        neighbour, or None where none is within the radius."""
        ny, nx = self.shape
        dx = self.xc[max(a, 0):nx + min(a, 0)] - self.xc[max(-a, 0):nx - max(a, 0)]
        dy = self.yc[max(b, 0):ny + min(b, 0)] - self.yc[max(-b, 0):ny - max(b, 0)]
        if np.min(np.abs(dx)) ** 2 + np.min(np.abs(dy)) ** 2 > self.radius ** 2:
            return None
        return filter_weights(np.hypot(dx[None, :], dy[:, None]), self.radius, self.kernel)

    def _stencil(self, u: np.ndarray) -> np.ndarray:
        """``(H u)`` on the grid ``(ny, nx)`` by one pass per offset."""
        ny, nx = self.shape
        A, B = self.reach
        out = np.zeros(self.shape)
        for b in range(-B, B + 1):
            rows_out, rows_in = slice(max(-b, 0), ny - max(b, 0)), slice(max(b, 0), ny + min(b, 0))
            for a in range(-A, A + 1):
                w = self._offset_weights(a, b)
                if w is not None:
                    out[rows_out, max(-a, 0):nx - max(a, 0)] += w * u[rows_in, max(a, 0):nx + min(a, 0)]
        return out

    def _prepare_fft(self, hx: float, hy: float) -> None:
        A, B = self.reach
        a, b = np.arange(-A, A + 1), np.arange(-B, B + 1)
        stencil = filter_weights(np.hypot(a[None, :] * hx, b[:, None] * hy), self.radius, self.kernel)
        ny, nx = self.shape
        self._fft_shape = (sp_fft.next_fast_len(ny + 2 * B, real=True), sp_fft.next_fast_len(nx + 2 * A, real=True))
        self._kernel_fft = sp_fft.rfft2(stencil, self._fft_shape)

    def _fft(self, u: np.ndarray) -> np.ndarray:
        """``(H u)`` on the grid by one FFT convolution with the (symmetric) stencil."""
        A, B = self.reach
        ny, nx = self.shape
        full = sp_fft.irfft2(sp_fft.rfft2(u, self._fft_shape) * self._kernel_fft, self._fft_shape)
        return full[B:B + ny, A:A + nx]

    def _apply(self, u: np.ndarray) -> np.ndarray:
        """``(H u)`` at the design elements for an element field ``u`` (E,)."""
        grid = np.asarray(u, dtype=float).reshape(self.shape)
        out = self._fft(grid) if self.method == "fft" else self._stencil(grid)
        return out.ravel()[self.design]

    def _on_design(self, values: np.ndarray) -> np.ndarray:
        u = np.zeros(self.shape[0] * self.shape[1])
        u[self.design] = values
        return u

    def forward(self, gamma: np.ndarray) -> np.ndarray:
        return (self._apply(self._on_design(gamma)) + self.b) / self.Hs

    def transpose(self, bar: np.ndarray) -> np.ndarray:
        return self._apply(self._on_design(bar / self.Hs))


@dataclass(frozen=True)
class Projection:
    """Smoothed Heaviside projection with sharpness ``beta`` and threshold ``eta`` (beta = 0: identity)."""

    beta: float
    eta: float = 0.5

    def forward(self, x: np.ndarray) -> np.ndarray:
        b, e = self.beta, self.eta
        if b < 1e-8:
            return np.asarray(x, dtype=float).copy()
        return (np.tanh(b * e) + np.tanh(b * (x - e))) / (np.tanh(b * e) + np.tanh(b * (1 - e)))

    def derivative(self, x: np.ndarray) -> np.ndarray:
        b, e = self.beta, self.eta
        if b < 1e-8:
            return np.ones_like(x, dtype=float)
        return b * (1 - np.tanh(b * (x - e)) ** 2) / (np.tanh(b * e) + np.tanh(b * (1 - e)))

    def transpose(self, x: np.ndarray, bar: np.ndarray) -> np.ndarray:
        return self.derivative(x) * bar


class DesignMap:
    """gamma (design elements) -> rho (all elements): filter, projection, fixed regions.

    The projection's sharpness ``beta`` is a continuation parameter: an argument of every
    call (the problem's :class:`~tofsi.core.blocks.Continuation` holds it), never stored here.
    """

    def __init__(self, mesh, filter_radius: float, eta: float = 0.5, kernel: str = "linear",
                 filter_fixed: bool = False):
        self.design = np.flatnonzero(mesh.region == DESIGN)
        self.base = (mesh.region == SOLID).astype(float)
        self.filter = DensityFilter(mesh, self.design, filter_radius, kernel,
                                    self.base if filter_fixed else None)
        self.eta = eta

    @property
    def size(self) -> int:
        return self.design.size

    def projection(self, beta: float) -> Projection:
        return Projection(beta, self.eta)

    def forward(self, gamma: np.ndarray, beta: float) -> np.ndarray:
        rho = self.base.copy()
        rho[self.design] = self.projection(beta).forward(self.filter.forward(gamma))
        return rho

    def transpose(self, gamma: np.ndarray, beta: float, rho_bar: np.ndarray) -> np.ndarray:
        """``d rho / d gamma`` transposed applied to ``rho_bar`` (E,) -> (n_design,)."""
        filtered = self.filter.forward(gamma)
        return self.filter.transpose(self.projection(beta).transpose(filtered, rho_bar[self.design]))
