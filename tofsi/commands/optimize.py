"""``tofsi optimize SCENE``: topology optimization with NLopt; ``--resume`` continues a run."""

from __future__ import annotations

import sys

import numpy as np

from tofsi.mesh import quality
from tofsi.optimization.optimize import Optimizer
from tofsi.runs.output import atomic_write, write_vtu
from tofsi.runs.plotting import plot_convergence, plot_design, region_outlines
from tofsi.optimization.problem import Problem
from tofsi.optimization.resume import check_checkpoint


class Pictures:
    """Design PNGs, a VTU series with its ParaView collection, and the convergence plot.

    Each design VTU carries, per element, the physical density ``density`` (rho),
    the design variables ``design_variable`` (gamma), the filtered densities
    ``filtered_density`` (before projection), the objective's sensitivity
    ``sensitivity`` (df/dgamma) -- the last three are NaN outside the design
    region -- the region tag, and where the fluid mesh moved (two-way stages) its
    per-element ``skewness`` and ``area_change``.
    """

    def __init__(self, ctx, problem):
        self.ctx, self.problem, self.series = ctx, problem, []

    def design_fields(self, gamma) -> dict:
        """Per-element design fields (NaN outside the design region)."""
        p = self.problem
        design = p.map.design
        fields = {}
        _, df = p.evaluate(gamma)                        # cached: computed by the optimizer
        for name, values in (("design_variable", gamma), ("filtered_density", p.map.filter.forward(gamma)),
                             ("sensitivity", df)):
            full = np.full(p.model.mesh.n_elements, np.nan)
            full[design] = values
            fields[name] = full
        return fields

    def __call__(self, iteration, gamma, state) -> None:
        p, mesh = self.problem, self.problem.model.mesh
        tag = iteration if iteration == "final" else f"{iteration:04d}"
        X = mesh.points if state.x is None else mesh.points + state.mesh_displacement
        point_data = {name: values[:mesh.n_nodes] for field in p.model.fields     # Q2 nodes: corners first
                      for name, values in field.point_data(p.model, state).items()}
        speed = np.linalg.norm(point_data["velocity"], axis=1) if "velocity" in point_data else None
        name = f"design_{tag}"
        c = p.params                                      # the stage this state was solved in
        stage = f"beta {c.beta:g}, penalty {c.penalty:g}" + (f", {c.coupling}" if c.coupling else "")
        when = "final design" if iteration == "final" else f"design at iteration {iteration}"
        plot_design(self.ctx.output / f"{name}.png", X, mesh.quads, state.rho, speed,
                    title=f"{p.scene.name}: {when} ({stage})", outlines=region_outlines(mesh.quads, mesh.region))
        cells = {"density": state.rho, "region": mesh.region, **self.design_fields(gamma)}
        if state.x is not None:                                  # the moved fluid mesh's quality
            cells["skewness"] = quality.skewness(X, mesh.quads)
            cells["area_change"] = quality.area_change(mesh.points, X, mesh.quads)
        write_vtu(self.ctx.output / f"{name}.vtu", X, {"quad": mesh.quads}, point_data, cells)
        if iteration != "final":
            self.series.append((iteration, f"{name}.vtu"))
            self._collection()

    def _collection(self) -> None:
        rows = "\n".join(f'    <DataSet timestep="{i}" file="{f}"/>' for i, f in self.series)
        text = ('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
                f"{rows}\n  </Collection>\n</VTKFile>\n")
        atomic_write(self.ctx.output / "design_series.pvd", lambda tmp: open(tmp, "w").write(text))


def run(scene, args, ctx) -> dict:
    problem = Problem(scene)
    pictures = Pictures(ctx, problem)
    d, s = scene.design, scene.optimizer

    out = sys.stderr if ctx.json else sys.stdout

    def line(it):
        if not ctx.quiet:
            notes = [f"min skewness {it.min_skewness:.3f}"] if it.min_skewness == it.min_skewness else []
            if it.load_steps:
                notes.append(f"inflow ramp {it.load_steps} steps, {it.load_cutbacks} cutbacks")
            if it.fallbacks:
                notes.append(f"{it.fallbacks} fallbacks")
            print(f"{it.iteration:5d} {it.stage:5d} {it.objective:12.5g} {it.volume:7.4f} "
                  f"{it.constraint:9.2e} {it.change:8.4f} {it.beta:5.1f} {it.time_s:7.1f}"
                  + ("  " + "; ".join(notes) if notes else ""), file=out, flush=True)

    def fallback(iteration, fallbacks, step, error):
        if not ctx.quiet:
            then = ("a bridging stage halfway from the previous stage first" if step is None else
                    f"back to the last good design, move limit {step:.3g}")
            print(f"{iteration:5d} fallback {fallbacks}: a trial design failed ({str(error)[:160]}); {then}",
                  file=out, flush=True)

    optimizer = Optimizer(problem, ctx.output, on_iteration=line, on_picture=pictures, on_fallback=fallback)
    if args.resume:                                  # same scene and mesh, before writing
        check_checkpoint(optimizer.checkpoint_path, problem)
    ctx.say(f"{scene.name}: {problem.n_design} design variables, {problem.model.mesh.n_elements} "
            f"elements; {s.algorithm}, {d.objective} subject to {d.constraint} fraction <= "
            f"{d.volume_fraction:g}; outputs in {ctx.output}")
    ctx.say(f"{'iter':>5s} {'stage':>5s} {'objective':>12s} {'volume':>7s} {'g':>9s} {'change':>8s} "
            f"{'beta':>5s} {'time':>7s}")
    ctx.begin()
    figures = optimizer.run(resume=args.resume)
    ctx.extra["stop_reason"] = figures["stop_reason"]
    plot_convergence(ctx.output / "convergence.png", [h.__dict__ for h in optimizer.history],
                     title=f"{scene.name}: {d.objective}", objective_label=problem.objective.axis_label())
    ctx.say(f"final {d.objective} {figures['objective']:.6g}, volume {figures['volume']:.4f} "
            f"(constraint {figures['constraint']:.2e}), non-discreteness "
            f"{figures['non_discreteness_percent']:.1f} %, {figures['iterations']} iterations, "
            f"{figures['wall_time_s']:.0f} s; stopped: {figures['stop_reason']}"
            + (f"; {figures['fallbacks']} fallbacks from failed trial designs" if figures["fallbacks"] else ""))
    figures["outputs"] = sorted(str(p) for p in ctx.output.iterdir() if not p.name.startswith("."))
    return figures
