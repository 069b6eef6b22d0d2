"""The distributed FSI problem at the wall design the slab-mover drivers move (``tests/mpi_slab_*.py``).

The scene's last continuation stage; densities 0.9 on the design quads of a wall at x = 1 m
(|x - 1| < 0.15 m, y < 0.6 m) and 0.1 elsewhere; ``bend`` the wall's downstream bend of unit
amplitude, ``((y / 0.6)^2 exp(-((x - 1) / 0.3)^2), 0)`` at every node [m].
"""

import numpy as np

import tofsi
from tofsi.coupling.coupled import continuation
from tofsi.parallel.fsi_problem import DistributedFsiProblem


def wall_problem(scene_path: str, overrides: list[str]):
    """``(problem, rho, bend)``: the distributed problem, the wall's densities and its unit bend (2n,)."""
    scene = tofsi.load_scene(scene_path, overrides)
    problem = DistributedFsiProblem(scene)
    problem.set_stage(continuation(scene, scene.design.n_stages - 1))
    mesh = problem.model.mesh
    centroids = mesh.centroids[problem.map.design]
    wall = (np.abs(centroids[:, 0] - 1.0) < 0.15) & (centroids[:, 1] < 0.6)
    rho = problem.serial.densities(np.where(wall, 0.9, 0.1))
    X, Y = mesh.points[:, 0], mesh.points[:, 1]
    bend = np.column_stack([(Y / 0.6) ** 2 * np.exp(-((X - 1.0) / 0.3) ** 2), 0.0 * X]).ravel()
    return problem, rho, bend
