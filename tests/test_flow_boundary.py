"""Flow boundaries on any side: exact Poiseuille flow along every direction, mass balance of
openings on two sides, exact segment pressure means, the older keys unchanged, bad input."""

import numpy as np
import pytest

from tofsi.core.config import build
from tofsi.core.errors import InputError
from tofsi.mesh.structured import SIDES, StructuredQuadMesh
from tofsi.physics.flow import Flow
from tofsi.physics.flow_boundary import INWARD, segment_weights, side_coordinate
from tofsi.fields.flow import FluidSettings

OPPOSITE = {"left": "right", "right": "left", "bottom": "top", "top": "bottom"}


def box(lx=1.2, ly=0.8, nx=6, ny=5):
    return StructuredQuadMesh(np.linspace(0, lx, nx + 1), np.linspace(0, ly, ny + 1))


def fluid(**tables):
    return build(FluidSettings, {"density": 0.0, "viscosity": 0.7, **tables}, "fluid")


@pytest.mark.parametrize("side", SIDES)
@pytest.mark.parametrize("outlet, parallel", [("zero-pressure", False), ("traction-free", True)])
def test_poiseuille_flow_from_any_side_is_exact(side, outlet, parallel):
    """Inflow over a whole side, the opposite side open: Taylor-Hood reproduces Poiseuille
    flow ``v = 4 U s (W - s) / W^2 n`` and the linear pressure ``dp/dn = -8 mu U / W^2``
    exactly, whichever way the channel points. Developed flow satisfies the do-nothing
    condition of the gradient form; of the traction-free condition only the normal part
    (its shear part mu dv_t/ds is not zero), so that outlet needs parallel_outflow."""
    mesh, U = box(), 1.3
    width = mesh.ys[-1] if side in ("left", "right") else mesh.xs[-1]
    length = mesh.xs[-1] if side in ("left", "right") else mesh.ys[-1]
    settings = fluid(**{side: {"inflow": [[0.0, width, U]]}, OPPOSITE[side]: {"open": [[0.0, width]]}},
                     outlet=outlet, parallel_outflow=parallel)
    flow = Flow(mesh, settings, stokes=True)
    w, _ = flow.solve()
    n = np.array(INWARD[side])
    P9 = mesh.points9()
    s = side_coordinate(side, P9)
    entry = P9[mesh.side_nodes9(side)[0]]
    depth = (P9 - entry) @ n                                   # distance from the inflow side
    v = w[:flow.n_velocity].reshape(-1, 2)
    np.testing.assert_allclose(v, (4 * U * s * (width - s) / width**2)[:, None] * n, atol=1e-10)
    mu = settings.viscosity
    p = w[flow.n_velocity:]
    np.testing.assert_allclose(p, 8 * mu * U / width**2 * (length - depth[:mesh.n_nodes]), atol=1e-9)
    assert flow.figures(w)["pressure_drop"] == pytest.approx(8 * mu * U / width**2 * length, rel=1e-10)


def outflow_through(flow, w, side, start, end):
    """Volume flow out of the channel through ``[start, end]`` of a side (Simpson per Q2 edge)."""
    mesh = flow.mesh
    nodes = mesh.side_nodes9(side)
    s = side_coordinate(side, mesh.points9()[nodes])
    vn = -w[:flow.n_velocity].reshape(-1, 2)[nodes] @ np.array(INWARD[side])
    vn = np.where((s > start - 1e-12) & (s < end + 1e-12), vn, 0.0)      # the wall around is still
    a, m, b = vn[:-2:2], vn[1:-1:2], vn[2::2]
    return float(np.sum((s[2::2] - s[:-2:2]) * (a + 4 * m + b) / 6))


def test_a_pipe_bend_with_an_outlet_on_the_bottom_conserves_mass():
    """Inflow on a segment of the left side, open outlet on a segment of the bottom: all that
    enters (2/3 U w) leaves through the bottom segment, nothing through the walls."""
    mesh = box(1.0, 1.0, 10, 10)
    settings = fluid(left={"inflow": [[0.7, 0.9, 1.0]]}, bottom={"open": [[0.7, 0.9]]})
    flow = Flow(mesh, settings, stokes=True)
    w, _ = flow.solve()
    assert flow.boundary.flux("inflow") == pytest.approx(2 / 3 * 0.2, rel=1e-12)
    assert outflow_through(flow, w, "bottom", 0.7, 0.9) == pytest.approx(2 / 3 * 0.2, rel=1e-10)
    for side in ("right", "top"):
        assert outflow_through(flow, w, side, 0.0, 1.0) == 0.0
    assert flow.figures(w)["pressure_drop"] > 0


def test_the_default_channel_is_the_older_inflow_left_and_open_right():
    """No side table: the whole left side inflow at fluid.inlet_velocity, the right side open, the
    same dofs fixed as listing these openings explicitly; fluid.inlets/outlets keep their meaning."""
    mesh = box()
    H = mesh.ys[-1]
    old = Flow(mesh, fluid(inlet_velocity=2.0), stokes=True)
    new = Flow(mesh, fluid(left={"inflow": [[0.0, H, 2.0]]}, right={"open": [[0.0, H]]}), stokes=True)
    np.testing.assert_array_equal(old.bc.fixed, new.bc.fixed)
    np.testing.assert_array_equal(old.values, new.values)
    fixed_right = np.isin(np.arange(new.size), new.bc.fixed)[2 * mesh.side_nodes9("right")]
    assert fixed_right.sum() == 2                           # only the two corners (walls)
    seg = Flow(mesh, fluid(inlets=[[0.2, 0.6, 1.0]], outlets=[[0.2, 0.6, 1.0]]), stokes=True)
    table = Flow(mesh, fluid(left={"inflow": [[0.2, 0.6, 1.0]]}, right={"outflow": [[0.2, 0.6, 1.0]]}),
                 stokes=True)
    np.testing.assert_array_equal(seg.bc.fixed, table.bc.fixed)
    np.testing.assert_array_equal(seg.values, table.values)
    assert not seg.open_outlet and seg.bc.is_fixed[2 * mesh.n_nodes9]      # closed: pressure pinned


def test_flux_of_two_segments_on_one_side_is_the_sum_of_their_parabolas():
    """Volume flow of a parabolic segment is 2/3 U w, and segments sharing a side add up (the
    segments end on grid lines, so the Q2 trace is the parabola itself)."""
    mesh = box(1.0, 1.0, 12, 12)                  # 1/6, 1/3, 2/3, 5/6 are grid lines
    b = Flow(mesh, fluid(inlets=[[1 / 6, 1 / 3, 1.0], [2 / 3, 5 / 6, 2.0]],
                         outlets=[[1 / 6, 1 / 3, 1.5], [2 / 3, 5 / 6, 1.5]]), stokes=True).boundary
    assert b.flux("inflow") == pytest.approx(2 / 3 * (1.0 + 2.0) / 6, rel=1e-13)
    assert b.flux("outflow") == pytest.approx(2 / 3 * (1.5 + 1.5) / 6, rel=1e-13)


def test_segment_integral_is_exact_for_linear_pressure():
    """``int_seg p ds`` of a linear pressure is its length times the value at its middle, for
    segments that do and do not end on nodes, on every side of a graded mesh."""
    mesh = StructuredQuadMesh([0.0, 0.1, 0.35, 0.5, 0.9, 1.0], [0.0, 0.2, 0.3, 0.65, 0.8])
    pressure = lambda x, y: 3.0 - 2.0 * x + 5.0 * y
    p = pressure(mesh.points[:, 0], mesh.points[:, 1])
    for side in SIDES:
        for start, end in ((0.05, 0.33), (0.2, 0.3), (0.0, 0.8)):
            mid = 0.5 * (start + end)
            x, y = {"left": (0.0, mid), "right": (1.0, mid), "bottom": (mid, 0.0), "top": (mid, 0.8)}[side]
            assert segment_weights(mesh, side, start, end) @ p == pytest.approx((end - start) * pressure(x, y),
                                                                                 rel=1e-13)


def test_parallel_outflow_fixes_the_tangential_velocity_of_open_segments():
    mesh = box()
    free = Flow(mesh, fluid(), stokes=True).bc.is_fixed
    parallel = Flow(mesh, fluid(parallel_outflow=True), stokes=True).bc.is_fixed
    right = mesh.side_nodes9("right")[1:-1]
    assert not free[2 * right + 1].any() and parallel[2 * right + 1].all()    # v_y
    assert not parallel[2 * right].any()                                      # v_x stays free


@pytest.mark.parametrize("tables, key", [
    ({"bottom": {"open": [[0.5, 1.5]]}}, "fluid.bottom.open[0]"),              # beyond the side
    ({"left": {"inflow": [[0.1, 0.5, 1.0]], "open": [[0.4, 0.7]]}}, "fluid.left.open[0]"),   # overlap
    ({"left": {"inflow": [[0.1, 0.5, 1.0]]}, "top": {"open": [[0.30, 0.31]]}}, "fluid.top.open[0]"),  # no node
    ({"top": {"open": [[0.0, 1.2]]}}, "fluid"),                               # no inflow
    ({"left": {"inflow": [[0.1, 0.5, 1.0]]}, "right": {"outflow": [[0.1, 0.5, 2.0]]}}, "fluid"),  # unbalanced
])
def test_bad_openings_are_input_errors_naming_the_key(tables, key):
    with pytest.raises(InputError) as err:
        Flow(box(), fluid(**tables), stokes=True)
    assert err.value.key == key


def test_a_segment_with_from_not_below_to_is_rejected_when_read():
    with pytest.raises(InputError) as err:
        fluid(bottom={"inflow": [[0.5, 0.5, 1.0]]})
    assert err.value.key == "fluid.bottom.inflow[0]"


def documented_openings():
    """The ```toml examples of docs/scenes.md's section on openings."""
    import re
    import tomllib
    from pathlib import Path
    text = (Path(__file__).resolve().parents[1] / "docs" / "scenes.md").read_text()
    section = text[text.index("## Where the flow enters and leaves"):]
    return [tomllib.loads(block) for block in re.findall(r"```toml\n(.*?)```", section, re.S)]


@pytest.mark.parametrize("example", documented_openings(), ids=lambda e: ",".join(
    f"{side}:{'+'.join(t)}" for side, t in e["fluid"].items()))
def test_documented_openings_solve_and_conserve_mass(example):
    """Each example of docs/scenes.md on the default 2 x 1 channel: Stokes flow is solved and
    what flows in through the inflow segments leaves through the outflow and open ones."""
    mesh = box(2.0, 1.0, 40, 20)
    flow = Flow(mesh, fluid(**example["fluid"]), stokes=True)
    w, report = flow.solve()
    assert report.converged
    q_in = flow.boundary.flux("inflow")
    q_out = sum(outflow_through(flow, w, o.side, o.start, o.end)
                for o in flow.boundary.openings if o.kind != "inflow")
    assert q_out == pytest.approx(q_in, rel=1e-10)
