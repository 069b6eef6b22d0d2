"""``tofsi optimize SCENE``: topology optimization with NLopt; ``--resume`` continues a run.

Under ``mpiexec -n P`` (P > 1) a flow-only scene, or a compliance FSI scene with a
small-strain structure (one-way, or two-way with any mover), is
optimized with its flow by slabs (:mod:`tofsi.parallel`): rank 0 runs the optimizer and
writes every output, the other ranks take part in each evaluation; other scenes are refused
by name (exit 2). With ``solver.linear_solver = "petsc"`` every rank
runs the serial problem instead, MUMPS factorizing across them.
"""

from __future__ import annotations

import sys
from contextlib import contextmanager

import numpy as np

from tofsi.commands.hints import describe
from tofsi.commands.solve import UNPHYSICAL
from tofsi.linalg.threads import mpi_size
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
    ``sensitivity`` (df/dgamma) -- outside the design region, where there are no
    design variables, the first two hold the element's fixed density and the
    sensitivity is 0 (no file holds a NaN) -- the region tag, and where the fluid
    mesh moved (two-way stages) its per-element ``skewness`` and ``area_change``.
    """

    def __init__(self, ctx, problem):
        self.ctx, self.problem = ctx, problem

    def design_fields(self, gamma, rho, sensitivity=None) -> dict:
        """Per-element design fields (outside the design region: the fixed density ``rho``, and
        a sensitivity of 0); ``sensitivity``: the gradient the optimizer recorded for ``gamma``
        (default: the problem's, cached from the optimizer's evaluation)."""
        p = self.problem
        design = p.map.design
        fields = {}
        df = p.evaluation(gamma).df if sensitivity is None else sensitivity
        for name, values, outside in (("design_variable", gamma, rho), ("sensitivity", df, 0.0),
                                      ("filtered_density", p.map.filter.forward(gamma), rho)):
            full = np.zeros(p.model.mesh.n_elements) + outside
            full[design] = values
            fields[name] = full
        return fields

    def __call__(self, iteration, gamma, state, sensitivity=None) -> None:
        p, mesh = self.problem, self.problem.model.mesh
        tag = iteration if iteration == "final" else f"{iteration:04d}"
        X = mesh.points if state.x is None else mesh.points + state.mesh_displacement
        point_data = {name: values[:mesh.n_nodes] for field in p.model.fields     # Q2 nodes: corners first
                      for name, values in field.point_data(p.model, state).items()}
        speed = np.linalg.norm(point_data["velocity"], axis=1) if "velocity" in point_data else None
        name = f"design_{tag}"
        c, coupling = p.stage.params, p.stage.coupling          # the stage this state was solved in
        stage = f"beta {c.beta:g}, penalty {c.penalty:g}" + (f", {coupling}" if coupling else "")
        when = "final design" if iteration == "final" else f"design at iteration {iteration}"
        plot_design(self.ctx.output / f"{name}.png", X, mesh.quads, state.rho, speed,
                    title=f"{p.scene.name}: {when} ({stage})", outlines=region_outlines(mesh.quads, mesh.region))
        cells = {"density": state.rho, "region": mesh.region, **self.design_fields(gamma, state.rho, sensitivity)}
        if state.x is not None:                                  # the moved fluid mesh's quality
            cells["skewness"] = quality.skewness(X, mesh.quads)
            cells["area_change"] = quality.area_change(mesh.points, X, mesh.quads)
        write_vtu(self.ctx.output / f"{name}.vtu", X, {"quad": mesh.quads}, point_data, cells)
        if iteration != "final":
            self._collection()

    def _collection(self) -> None:
        """The ParaView collection of every design VTU in the folder (a resumed run's earlier
        ones too: the folder, not this process, holds the series)."""
        found = sorted((int(p.stem[len("design_"):]), p.name) for p in self.ctx.output.glob("design_*.vtu")
                       if p.stem[len("design_"):].isdigit())
        rows = "\n".join(f'    <DataSet timestep="{i}" file="{f}"/>' for i, f in found)
        text = ('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
                f"{rows}\n  </Collection>\n</VTKFile>\n")
        atomic_write(self.ctx.output / "design_series.pvd", lambda tmp: open(tmp, "w").write(text))


@contextmanager
def design_problem(scene):
    """The scene's design problem: the serial :class:`Problem`; under ``mpiexec`` (more than one
    rank, ``solver.linear_solver`` not ``petsc``) the distributed one (flow-only or FSI), driven from rank 0 (the
    block gets None on the other ranks, which served every evaluation when it begins)."""
    if mpi_size() < 2 or scene.solver.linear_solver == "petsc":
        yield Problem(scene)
        return
    from tofsi.parallel.flow_problem import leading
    from tofsi.parallel.fsi_problem import problem_class
    with leading(scene, problem_class(scene)) as problem:
        yield problem


def run(scene, args, ctx) -> dict:
    with design_problem(scene) as problem:
        return {} if problem is None else optimize(problem, scene, args, ctx)


def optimize(problem, scene, args, ctx) -> dict:
    """Optimize ``problem`` (a :class:`~tofsi.optimization.protocol.DesignProblem`) with the
    progress lines, pictures and summary of the command line."""
    pictures = Pictures(ctx, problem)
    d, s = scene.design, scene.optimizer

    out = sys.stderr if ctx.json else sys.stdout

    def line(it):
        if not ctx.quiet:
            notes = ([f"min skewness {it.min_skewness:.3f}", f"interface gap {it.max_interface_gap:.2g} m"]
                     if it.min_skewness == it.min_skewness else [])
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
            print(f"{iteration:5d} fallback {fallbacks}: a trial design failed ({describe(error, 160)}); {then}",
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
    if not figures["physical"]:                      # written, flagged, exit 5 unless accepted
        ctx.warn(f"the final design's state is no physical state: {figures['unphysical']}"
                 + ("" if args.allow_unphysical else
                    f"; exit status {UNPHYSICAL} (--allow-unphysical accepts these figures)"))
        if not args.allow_unphysical:
            ctx.exit_status = UNPHYSICAL
    figures["warnings"] = ctx.extra.get("warnings", [])
    plot_convergence(ctx.output / "convergence.png", [h.__dict__ for h in optimizer.history],
                     title=f"{scene.name}: {d.objective}", objective_label=problem.objective.axis_label())
    ctx.say(f"final {d.objective} {figures['objective']:.6g}, volume {figures['volume']:.4f} "
            f"(constraint {figures['constraint']:.2e}), non-discreteness "
            f"{figures['non_discreteness_percent']:.1f} %, {figures['iterations']} iterations, "
            f"{figures['wall_time_s']:.0f} s; stopped: {figures['stop_reason']}"
            + (f"; {figures['fallbacks']} fallbacks from failed trial designs" if figures["fallbacks"] else "")
            + "".join(f"; the {name} bound is violated (g = {g:+.3g} > 0)" for name, g in figures["violated"].items()))
    figures["outputs"] = sorted(str(p) for p in ctx.output.iterdir() if not p.name.startswith("."))
    return figures
