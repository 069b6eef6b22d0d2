"""Density-dependent layered stiffening: layers grown from the densities by smooth dilation.

For 0/1 densities the layers are exactly the breadth-first element layers of the fixed solid
(tofsi.mesh.layers, an independent algorithm); for gray densities the factors are smooth, and the
gradient through them is exact (central differences, and two-way Taylor tests per mover).
"""

import numpy as np
import pytest

import tofsi
from adjoint.checks import taylor_test
from tofsi.mesh.channel import build_mesh
from tofsi.mesh.layers import element_layers, stiffening_field
from tofsi.mesh.structured import SOLID
from tofsi.physics.indicators import DensityLayers

from conftest import load


@pytest.mark.parametrize("name", ["beam_in_channel", "foil_in_channel", "beam_in_channel_optimization"])
def test_for_0_1_densities_the_layers_are_the_breadth_first_layers(name):
    scene = load(name, "mesh.h_min=0.05", "mesh.h_max=0.1")
    mesh = build_mesh(scene.geometry, scene.mesh)
    rho = (mesh.region == SOLID).astype(float)
    factors = [3.0, 2.0, 1.5, 1.2]
    bfs = stiffening_field(element_layers(mesh.incidence, mesh.interface_nodes, mesh.region != SOLID,
                                          n_layers=len(factors)), factors)
    bfs[mesh.region == SOLID] = 1.0
    f = DensityLayers(mesh.quads, mesh.n_nodes, factors).factors(rho)
    np.testing.assert_array_equal(f, bfs)
    assert set(np.unique(f)) == {1.0, *factors}                  # every layer is there


def test_gray_factors_are_smooth_and_their_transpose_is_exact():
    scene = load("beam_in_channel_optimization", "mesh.h_min=0.1", "mesh.h_max=0.1")
    mesh = build_mesh(scene.geometry, scene.mesh)
    layers = DensityLayers(mesh.quads, mesh.n_nodes, [2.5, 1.7])
    rng = np.random.default_rng(7)
    rho, d, f_bar = rng.uniform(0, 1, mesh.n_elements), rng.normal(size=mesh.n_elements), rng.normal(size=mesh.n_elements)
    f = layers.factors(rho)
    assert np.all((f >= 1.0) & (f <= 2.5))                       # between unstiffened and layer 1
    h = 1e-6
    fd = f_bar @ (layers.factors(rho + h * d) - layers.factors(rho - h * d)) / (2 * h)
    assert layers.transpose(rho, f_bar) @ d == pytest.approx(fd, rel=1e-7)


MOVERS = {"yeoh": ["mover.name=yeoh"], "linear": ["mover.name=linear"],
          "spring-1": ["mover.name=spring", "mover.spring.increments=1", "mover.spring.diagonals=both"],
          "spring-3": ["mover.name=spring", "mover.spring.increments=3", "mover.spring.diagonals=both"]}
BASE = ["mesh.h_min=0.1", "mesh.h_max=0.1", "fluid.alpha_max=1e3", "fluid.newton_tol=1e-13",
        "design.filter_radius=0.15", "structure.youngs_modulus=2e4", "coupled.tol=1e-12",
        "mover.yeoh.newton_tol=1e-13", "mover.linear.linear_tol=1e-14", "mover.spring.linear_tol=1e-14",
        "effects.coupling=two-way", "structure.load_exponent=3", "mover.layers=[3.0, 1.8]"]


@pytest.mark.parametrize("mover", list(MOVERS))
def test_two_way_gradient_through_density_dependent_stiffening(mover):
    P = tofsi.Problem(load("beam_in_channel_optimization", *BASE, *MOVERS[mover]))
    assert P.model.motion.density_layers is not None
    rng = np.random.default_rng(11)
    gamma = rng.uniform(0.05, 0.95, P.n_design)
    d = rng.normal(size=P.n_design)
    f0, df = P.evaluate(gamma)
    t = taylor_test(lambda g: P.evaluate(g)[0], gamma, df, d, eps0=1e-2, steps=4, f0=f0)
    assert t.min_rate > 1.9, t
    fixed = tofsi.Problem(load("beam_in_channel_optimization", *BASE, *MOVERS[mover],
                               "mover.layers_from=solid"))
    assert fixed.evaluate(gamma)[0] != pytest.approx(f0, rel=1e-9)   # the stiffening acts
