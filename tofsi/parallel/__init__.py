"""Distributed assembly and solves under MPI with PETSc (optional: see ``docs/parallel.md``).

* :class:`~tofsi.parallel.partition.SlabPartition` -- element slabs by rank and the
  contiguous dof numbering;
* :class:`~tofsi.parallel.flow_system.DistributedFlow` -- the flow's Newton solve with
  each rank assembling only its slab, FGMRES with a Schur fieldsplit (GAMG or hypre),
  and the transposed solve of its converged Jacobian;
* :class:`~tofsi.parallel.flow_adjoint.SlabObjective` -- a flow objective and its adjoint
  gradient in the densities, by slabs;
* :class:`~tofsi.parallel.flow_problem.DistributedFlowProblem` -- a flow-only design
  problem's ``evaluate`` / ``constraints`` (replicated design map and volume weights);
* :mod:`tofsi.parallel.optimize_flow` -- MMA on rank 0 with the design broadcast
  (``mpiexec -n P python -m tofsi.parallel.optimize_flow SCENE``).
"""
