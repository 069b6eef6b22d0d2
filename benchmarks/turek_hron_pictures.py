"""The Turek & Hron benchmark's picture (``python -m benchmarks.turek_hron report --pictures DIR``):
the FSI1 flow around the cylinder and flag, and the CSM1 flag under its weight."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.turek_hron import CASES, SCENES, h_min


def pictures(output: Path, folder: Path, fsi_level: int, csm_level: int) -> None:
    """The FSI1 flow around the cylinder and flag (speed, the flag's deflection magnified) and the
    CSM1 flag under its weight at true scale."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import tofsi
    from tofsi.mesh.channel import named_solids
    from tofsi.coupling.coupled import CoupledModel
    from tofsi.runs.plotting import element_boundary
    folder.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(2, 1, figsize=(9, 6.2), layout="constrained")
    for ax, case, level in ((axes[0], "fsi1", fsi_level), (axes[1], "csm1", csm_level)):
        c = CASES[case]
        scene = tofsi.load_scene(SCENES / f"{c.scene}.toml", [f"mesh.h_min={h_min(level)}", *c.overrides])
        model = CoupledModel(scene)
        state = model.solve(model.densities())
        mesh = model.mesh
        solids = named_solids(scene.geometry, mesh)
        U = state.u.reshape(-1, 2)
        if case == "fsi1":
            X = mesh.points + state.mesh_displacement
            speed = np.linalg.norm(model.flow.corner_velocity(state.w), axis=1)
            tpc = ax.tripcolor(X[:, 0], X[:, 1], np.vstack([mesh.quads[:, [0, 1, 2]], mesh.quads[:, [0, 2, 3]]]),
                               speed, shading="gouraud", cmap="viridis")
            fig.colorbar(tpc, ax=ax, label="|v| [m/s]")
            scale = 50.0
            edges = element_boundary(mesh.quads, np.isin(np.arange(mesh.n_elements), solids["flag"]))
            for pts, style, label in ((mesh.points, "w:", "flag at rest"),
                                      (mesh.points + scale * U, "r-", f"flag deformed (x{scale:g})")):
                for i, e in enumerate(edges):
                    ax.plot(pts[e, 0], pts[e, 1], style, lw=1.0, label=label if i == 0 else None)
            cyl = element_boundary(mesh.quads, np.isin(np.arange(mesh.n_elements), solids["cylinder"]))
            for i, e in enumerate(cyl):
                ax.plot(X[e, 0], X[e, 1], "k-", lw=0.8, label="cylinder (staircase)" if i == 0 else None)
            f = model.figures(state)
            ax.set_title(f"FSI1 (h_min {1e3 * h_min(level):g} mm): drag {f['drag']:.3f} N/m, lift {f['lift']:.4f} N/m, "
                         f"u_y(A) {1e3 * f['uy_A']:.4f} mm", fontsize=9)
            ax.set_xlim(0.1, 0.9)
            ax.set_ylim(0.0, 0.41)
            ax.legend(loc="lower right", fontsize=7, facecolor="0.55", framealpha=0.9)
        else:
            edges = element_boundary(mesh.quads, np.isin(np.arange(mesh.n_elements), solids["flag"]))
            for pts, style, label in ((mesh.points, "k:", "flag at rest"), (mesh.points + U, "b-", "flag deformed (true scale)")):
                for i, e in enumerate(edges):
                    ax.plot(pts[e, 0], pts[e, 1], style, lw=1.0, label=label if i == 0 else None)
            circle = plt.Circle((0.2, 0.2), 0.05, color="0.6", label="cylinder")
            ax.add_patch(circle)
            f = model.figures(state)
            ax.plot([0.6 + f["ux_A"]], [0.2 + f["uy_A"]], "ro", ms=4, label="A")
            ax.set_title(f"CSM1 (h_min {1e3 * h_min(level):g} mm): u_x(A) {1e3 * f['ux_A']:.3f} mm, "
                         f"u_y(A) {1e3 * f['uy_A']:.2f} mm", fontsize=9)
            ax.set_xlim(0.1, 0.7)
            ax.set_ylim(0.1, 0.26)
            ax.legend(loc="lower left", fontsize=7)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    fig.savefig(folder / "turek_hron.png", dpi=110)
    print(f"wrote {folder / 'turek_hron.png'}")
