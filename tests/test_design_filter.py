"""The density filter applied as a stencil on the structured grid (offset by offset, or by FFT
on uniform axes) against the matrix filter it replaces (``filter_oracle.MatrixFilter``, the
k-d tree's pairs within the radius): the same filtered densities to round-off, on uniform and
graded meshes, with and without the fixed elements, both kernels; its transpose by the
dot-product test; and what it stores."""

import numpy as np
import pytest

from tofsi.mesh.channel import build_mesh
from tofsi.optimization.design import DensityFilter, DesignMap
from tofsi.mesh.grading import graded_axis
from tofsi.mesh.structured import DESIGN, FLUID, SOLID, StructuredQuadMesh

from conftest import load
from filter_oracle import MatrixFilter


def beam_mesh(h):
    scene = load("beam_in_channel_optimization", f"mesh.h_min={h}", f"mesh.h_max={h}")
    return build_mesh(scene.geometry, scene.mesh)


def graded_mesh():
    """Graded on both axes (growth 1.3 away from a solid, h 0.02 -> 0.1), a design region
    around the solid and a fixed solid inside it."""
    xs = graded_axis(2.0, [0.5, 0.9, 1.1, 1.6], [(0.9, 1.1)], 0.02, 0.1, 1.3)
    ys = graded_axis(1.0, [0.3, 0.45, 0.55, 0.8], [(0.45, 0.55)], 0.02, 0.1, 1.3)
    mesh = StructuredQuadMesh(xs, ys)
    c = mesh.centroids
    region = np.full(mesh.n_elements, FLUID, dtype=np.int8)
    region[(c[:, 0] > 0.5) & (c[:, 0] < 1.6) & (c[:, 1] > 0.3) & (c[:, 1] < 0.8)] = DESIGN
    region[(c[:, 0] > 0.9) & (c[:, 0] < 1.1) & (c[:, 1] > 0.45) & (c[:, 1] < 0.55)] = SOLID
    return mesh.with_regions(region)


CASES = {          # mesh, radius, kernel, fixed, method
    "uniform stencil": (lambda: beam_mesh(0.025), 0.12, "linear", False, "stencil"),
    "uniform fft": (lambda: beam_mesh(0.025), 0.12, "linear", False, "fft"),
    "piecewise uniform (h 0.048-0.052)": (lambda: beam_mesh(0.05), 0.12, "linear", False, None),
    "uniform fft, fixed, circular": (lambda: beam_mesh(0.025), 0.11, "circular", True, "fft"),
    "uniform stencil, fixed, circular": (lambda: beam_mesh(0.025), 0.11, "circular", True, "stencil"),
    "radius below an element": (lambda: beam_mesh(0.025), 0.01, "linear", False, None),
    "graded": (graded_mesh, 0.09, "linear", False, "stencil"),
    "graded, fixed, circular": (graded_mesh, 0.09, "circular", True, "stencil"),
}


@pytest.mark.parametrize("case", CASES)
def test_the_stencil_filter_equals_the_matrix_filter(case):
    make, r, kernel, fixed, method = CASES[case]
    mesh = make()
    design = np.flatnonzero(mesh.region == DESIGN)
    base = (mesh.region == SOLID).astype(float)
    stencil = DensityFilter(mesh, design, r, kernel, base if fixed else None, method=method)
    oracle = MatrixFilter(mesh, r, kernel, fixed)
    rng = np.random.default_rng(1)
    gamma = rng.uniform(0, 1, design.size)
    np.testing.assert_allclose(stencil.Hs, oracle.Hs, rtol=1e-13)
    np.testing.assert_allclose(stencil.forward(gamma), oracle.forward(gamma), rtol=1e-13, atol=1e-15)
    bar = rng.normal(size=design.size)
    np.testing.assert_allclose(stencil.transpose(bar), oracle.transpose(bar), rtol=1e-12,
                               atol=1e-13 * np.abs(oracle.transpose(bar)).max())   # FFT: round-off of the largest
    a, y = rng.normal(size=design.size), rng.normal(size=design.size)
    linear = stencil.forward(a) - stencil.forward(np.zeros(design.size))
    assert y @ linear == pytest.approx(a @ stencil.transpose(y), rel=1e-13)


def test_the_filter_on_a_uniform_grid_picks_the_fft_past_a_few_offsets_and_stores_no_matrix():
    mesh = beam_mesh(0.0125)                   # 160 x 80, radius 0.05 = 4 elements: 81 offsets
    fine = DesignMap(mesh, 0.05).filter
    assert fine.method == "fft"
    assert DesignMap(mesh, 0.02).filter.method == "stencil"
    assert fine.nbytes < 60 * mesh.n_elements           # the matrix held ~600 bytes per element here
    oracle = MatrixFilter(mesh, 0.05)
    assert fine.nbytes < 0.1 * (oracle.H.data.nbytes + oracle.H.indices.nbytes)
