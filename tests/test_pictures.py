"""Pictures a reader can read: nothing overlaps, axes have units, colour bars names; the design
VTU carries the design variables, the filtered densities and the sensitivities."""

import meshio
import numpy as np
import pytest

import tofsi
import tofsi.runs.plotting as plotting
from tofsi.core.registry import OBJECTIVES
from tofsi.mesh.channel import build_mesh
from tofsi.commands.context import RunContext
from tofsi.commands.optimize import Pictures

from conftest import scene_path

LONG = ("foil_in_channel: FAILED (spring mover: 12 inverted element(s); worst element 652 at "
        "[0.7625, 0.53820624058174]; the spring analogy inverted elements with "
        "mover.spring.increments = 1)")


@pytest.fixture
def figures(monkeypatch):
    """The figures the plotting functions would save (drawn, not written)."""
    kept = []

    def keep(fig, path):
        fig.canvas.draw()
        kept.append(fig)
    monkeypatch.setattr(plotting, "save", keep)
    yield kept
    for fig in kept:
        plotting.plt.close(fig)


def is_colorbar(ax) -> bool:
    return ax.get_label() == "<colorbar>"


def overlap(a, b, slack=1.0) -> bool:
    return (min(a.x1, b.x1) - max(a.x0, b.x0) > slack) and (min(a.y1, b.y1) - max(a.y0, b.y0) > slack)


def check_layout(fig) -> None:
    """No title over an axes or a colour bar, no two titles on each other, no panel's labels or
    tick labels over another panel or colour bar; colour bars and axes are labelled."""
    renderer = fig.canvas.get_renderer()
    axes = fig.axes
    titles = [t for t in fig.texts if t.get_text()] + [ax.title for ax in axes if ax.get_title()]
    frames = [ax.get_window_extent(renderer) for ax in axes]
    for t in titles:
        box = t.get_window_extent(renderer)
        assert not any(overlap(box, f) for f in frames), f"title {t.get_text()[:40]!r} overlaps an axes"
    for legend in fig.legends:                                   # figure legends sit outside
        assert not any(overlap(legend.get_window_extent(renderer), f) for f in frames)
    for i, a in enumerate(titles):
        for b in titles[i + 1:]:
            assert not overlap(a.get_window_extent(renderer), b.get_window_extent(renderer))
    tight = [ax.get_tightbbox(renderer) for ax in axes]
    for i in range(len(axes)):
        for j in range(i + 1, len(axes)):
            if axes[i].get_position().bounds == axes[j].get_position().bounds:
                continue                                          # twin axes share their frame
            assert not overlap(tight[i], tight[j]), f"panels {i} and {j} overlap"
    for k, ax in enumerate(axes):
        twin = any(a.get_position().bounds == ax.get_position().bounds for a in axes[:k])
        if is_colorbar(ax):
            assert ax.get_ylabel() or ax.get_xlabel(), "a colour bar without a name"
        else:
            shared = any(a.get_xlabel() for a in ax.get_shared_x_axes().get_siblings(ax))   # a column
            assert ax.get_ylabel() and (twin or shared), "an axis without a label"


@pytest.fixture(scope="module")
def foil_mesh():
    scene = tofsi.load_scene(scene_path("foil_in_channel"), ["mesh.h_min=0.05", "mesh.h_max=0.1"])
    return build_mesh(scene.geometry, scene.mesh)


def test_a_failed_mesh_picture_keeps_its_long_title_off_the_colour_bar(figures, foil_mesh):
    m = foil_mesh
    skew = np.linspace(-0.5, 1.0, m.n_elements)
    plotting.plot_mesh("x.png", m.points, m.quads, skew, m.interface_edges, title=LONG, vmin=-0.5, vmax=1)
    check_layout(figures[0])
    assert figures[0].axes[0].get_xlabel() == "x [m]"


def test_deformed_solution_nodal_and_design_pictures(figures, foil_mesh):
    m = foil_mesh
    rho = np.linspace(0, 1, m.n_elements)
    plotting.plot_mesh("d.png", m.points, m.quads, rho, title="beam_in_channel_optimization: structure "
                       "displacement (magnified 1.5e+03 times)", label="density rho (0 fluid, 1 solid)",
                       cmap="Greys", vmin=0, vmax=1)
    plotting.plot_nodal("n.png", m.points, m.quads, m.points[:, 0], title="velocity magnitude",
                        label="|v| [m/s]")
    plotting.plot_design("p.png", m.points, m.quads, rho, speed=m.points[:, 1], title=LONG)
    for fig in figures:
        check_layout(fig)
    names = {ax.get_ylabel() for ax in figures[2].axes if is_colorbar(ax)}
    assert names == {"flow speed |v| [m/s]", "density rho (0 fluid, 1 solid)"}


def test_convergence_has_units_and_a_legend_for_its_stage_lines(figures):
    history = [{"iteration": k, "objective": 50.0 * 0.7 ** k, "constraint": -0.1 / (k + 1),
                "stage": k // 4, "beta": 2.0 ** (k // 4)} for k in range(14)]
    plotting.plot_convergence("c.png", history, title="beam_in_channel_optimization: compliance",
                              objective_label=OBJECTIVES.get("compliance").axis_label())
    fig = figures[0]
    check_layout(fig)
    legend = [t.get_text() for lg in fig.legends for t in lg.get_texts()]
    assert legend == ["compliance [J/m]", "volume constraint g", "new continuation stage"]
    stage_lines = [ln for ln in fig.axes[0].get_lines() if ln.get_linestyle() == "--"]
    assert [ln.get_xdata()[0] for ln in stage_lines] == [4, 8, 12]
    assert fig.axes[0].get_xlabel() == "design iteration"


@pytest.mark.parametrize("shape", ["lines", "heat maps"])
def test_study_panels_do_not_overlap(figures, shape):
    rows = []
    for name in ("spring", "yeoh"):
        for a in (1.0, 2.0, 3.0):
            for b in ((1.0, 2.0) if shape == "heat maps" else (None,)):
                row = {"mover.name": name, "mover.layers[0]": a, "min_skewness": 0.3 + 0.01 * a,
                       "min_area_change": 0.5, "max_area_change": 1.5, "wall_time_s": 0.1, "status": "ok"}
                if b is not None:
                    row["mover.layers[1]"] = b
                rows.append(row)
    rows[1] = dict(rows[1], status="failed", converged=False, min_skewness=-0.2)
    keys = ["mover.layers[0]", "mover.name"] + (["mover.layers[1]"] if shape == "heat maps" else [])
    assert plotting.plot_sweep("s.png", rows, keys, title="foil_in_channel: a study with a long title "
                               "that would once have run over the panels of the figure")
    check_layout(figures[0])


def test_the_design_vtu_carries_design_variables_filtered_densities_and_sensitivities(tmp_path):
    """Against independent truths: gamma as given, H gamma / Hs by the filter's definition
    (weights r - distance), the projection's formula, and the objective's adjoint gradient."""
    scene = tofsi.load_scene(scene_path("beam_in_channel_optimization"),
                             ["mesh.h_min=0.1", "mesh.h_max=0.1", "design.filter_radius=0.25"])
    problem = tofsi.Problem(scene)
    gamma = np.random.default_rng(3).uniform(0.1, 0.9, problem.n_design)
    state = problem.solve(gamma)
    Pictures(RunContext(output=tmp_path), problem)("final", gamma, state)
    cells = meshio.read(tmp_path / "design_final.vtu").cell_data
    field = {k: np.asarray(v[0]) for k, v in cells.items()}
    design = problem.map.design
    outside = np.setdiff1d(np.arange(problem.model.mesh.n_elements), design)
    for name in ("design_variable", "filtered_density", "sensitivity"):
        assert np.all(np.isnan(field[name][outside])) and np.all(np.isfinite(field[name][design]))
    np.testing.assert_array_equal(field["design_variable"][design], gamma)
    c = problem.model.mesh.centroids[design]
    r = scene.design.filter_radius
    d = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=2)
    w = np.maximum(r - d, 0.0)
    filtered = w @ gamma / w.sum(axis=1)
    np.testing.assert_allclose(field["filtered_density"][design], filtered, rtol=1e-12)
    b, e = problem.params.beta, scene.design.eta
    projected = (np.tanh(b * e) + np.tanh(b * (filtered - e))) / (np.tanh(b * e) + np.tanh(b * (1 - e)))
    np.testing.assert_allclose(field["density"][design], projected, rtol=1e-12)
    np.testing.assert_allclose(field["sensitivity"][design], problem.evaluate(gamma)[1], rtol=1e-12)


# ---- issue 25: pictures that explain themselves -------------------------------------------------
def legend_texts(fig) -> list[str]:
    return [t.get_text() for lg in fig.legends for t in lg.get_texts()]


def test_the_outline_of_an_element_set_is_its_perimeter(foil_mesh):
    """element_boundary of the solid: the edges no other solid element shares. Truth: the foil is
    the rectangle [0.75, 1.25] x [0.475, 0.525], perimeter 2 (0.5 + 0.05) = 1.1 m."""
    from tofsi.mesh.structured import SOLID
    m = foil_mesh
    edges = plotting.element_boundary(m.quads, m.region == SOLID)
    length = np.linalg.norm(m.points[edges[:, 0]] - m.points[edges[:, 1]], axis=1).sum()
    assert length == pytest.approx(1.1, rel=1e-12)
    assert sorted(map(tuple, np.sort(edges, axis=1))) == sorted(map(tuple, np.sort(m.interface_edges, axis=1)))


def test_field_pictures_name_every_outline_and_patch_in_a_legend(figures, foil_mesh):
    """The velocity picture did not outline the design region or the solid; nothing said what
    the grey, the red or a dashed line is."""
    from tofsi.mesh.structured import DESIGN
    m = foil_mesh
    region = m.region.copy()
    region[(m.centroids[:, 0] > 0.3) & (m.centroids[:, 0] < 0.6)] = DESIGN
    outlines = plotting.region_outlines(m.quads, region)
    rho = (region != 0).astype(float)
    plotting.plot_nodal("n.png", m.points, m.quads, m.points[:, 0], title="velocity magnitude", label="|v| [m/s]",
                        grey=rho > 0.5, outlines=outlines)
    plotting.plot_design("d.png", m.points, m.quads, rho, speed=m.points[:, 1], title="design", outlines=outlines)
    skew = np.linspace(-0.5, 1.0, m.n_elements)
    plotting.plot_mesh("m.png", m.points, m.quads, skew, m.interface_edges, title="moved", grey=region == 1,
                       outlines=[plotting.Outline(plotting.element_boundary(m.quads, skew < 0), "inverted element",
                                                  "black")])
    for fig in figures:
        check_layout(fig)
    assert legend_texts(figures[0]) == ["solid (density > 0.5)", "design region", "fixed solid"]
    assert legend_texts(figures[1]) == ["design region", "fixed solid"]
    assert legend_texts(figures[2]) == ["solid", "fluid-structure interface", "inverted element"]
    bar = [ax for ax in figures[2].axes if is_colorbar(ax)][0]
    assert bar.get_ylabel() == "skewness (1 square corners, 0 degenerate, < 0 inverted)"


def test_the_convergence_legend_names_the_mesh_quality_lines_and_every_stage_is_labelled(figures):
    """The lower panel's lines were not in the legend, and the first stage had no label."""
    history = [{"iteration": k, "objective": 50.0 * 0.7 ** k, "constraint": -0.1 / (k + 1), "stage": k // 4,
                "beta": 2.0 ** (k // 4), "coupling": "two-way" if k >= 8 else "one-way",
                "min_skewness": 0.8 if k >= 8 else np.nan, "min_area_change": 0.9 if k >= 8 else np.nan,
                "max_area_change": 1.1 if k >= 8 else np.nan} for k in range(12)]
    plotting.plot_convergence("c.png", history, title="two-way", objective_label="compliance [J/m]")
    fig = figures[0]
    check_layout(fig)
    assert legend_texts(fig) == ["compliance [J/m]", "volume constraint g", "new continuation stage",
                                 "min element skewness", "min area change A / A0", "max area change A / A0"]
    labels = [t.get_text() for t in fig.axes[0].texts]
    assert labels == ["beta 1, one-way", "beta 2, one-way", "beta 4, two-way"]


def test_design_pictures_say_which_design_and_stage(figures, tmp_path):
    """A title read "design at iteration final"; now "final design (beta ..., penalty ...)"."""
    scene = tofsi.load_scene(scene_path("beam_in_channel_optimization"), ["mesh.h_min=0.1", "mesh.h_max=0.1"])
    problem = tofsi.Problem(scene)
    gamma = problem.initial_design()
    state = problem.solve(gamma)
    pictures = Pictures(RunContext(output=tmp_path), problem)
    pictures("final", gamma, state)
    pictures(7, gamma, state)
    titles = [fig.texts[0].get_text().replace("\n", " ") for fig in figures]
    beta, penalty = problem.params.beta, problem.params.penalty
    assert titles == [f"beam_in_channel_optimization: final design (beta {beta:g}, penalty {penalty:g})",
                      f"beam_in_channel_optimization: design at iteration 7 (beta {beta:g}, penalty {penalty:g})"]
    assert legend_texts(figures[0]) == ["design region", "fixed solid"]
