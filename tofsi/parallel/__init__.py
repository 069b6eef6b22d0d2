"""Distributed assembly and solves under MPI with PETSc (optional: see ``docs/parallel.md``).

* :class:`~tofsi.parallel.partition.SlabPartition` -- element slabs by rank and the
  contiguous dof numbering;
* :class:`~tofsi.parallel.flow_system.DistributedFlow` -- the flow's Newton solve with
  each rank assembling only its slab, FGMRES with a Schur fieldsplit (GAMG or hypre),
  and the transposed solve of its converged Jacobian;
* :class:`~tofsi.parallel.flow_adjoint.SlabObjective` -- a flow objective and its adjoint
  gradient in the densities, by slabs;
* :class:`~tofsi.parallel.flow_problem.DistributedFlowProblem` -- a flow-only design
  problem (a :class:`~tofsi.optimization.protocol.DesignProblem`: replicated design map and
  volume weights, the flow by slabs), driven from rank 0 by ``tofsi optimize`` under
  ``mpiexec -n P`` (:func:`~tofsi.parallel.flow_problem.leading`, :func:`~tofsi.parallel.flow_problem.serve`);
* :class:`~tofsi.parallel.slab_flow.SlabCoupling` -- the fluid load and the coupling partials on a
  rank's slab with the serial kernels (:class:`~tofsi.parallel.slab_flow.SlabFlow`: a Flow restricted
  to the slab's elements), summed over ranks;
* :class:`~tofsi.parallel.slab_matrix.SlabMatrix` -- a matrix on the mesh's node dofs by slabs, MUMPS
  across the ranks; :class:`~tofsi.parallel.slab_structure.SlabStructure` -- the small-strain
  stiffness on it;
* :class:`~tofsi.parallel.slab_mover.SlabMover` -- a residual-form mesh mover (Yeoh, linear or the
  spring in one increment) by slabs: its element kernels on a rank's quads, its tangent on a
  ``SlabMatrix``, the serial Yeoh mover's Newton with load steps and cutbacks
  (:class:`movers.newton.LoadStepNewton`), its
  transposed solve and partials;
* :class:`~tofsi.parallel.slab_increments.SlabIncrementMover` -- a mover in increments (the spring
  analogy, linear elasticity with ``increments > 1``) by slabs: each increment's element matrices on
  a rank's quads, its system on its own ``SlabMatrix``, the tangent and reverse sweeps;
* :class:`~tofsi.parallel.fsi_problem.DistributedFsiProblem` -- compliance FSI (small strain, one-way
  or two-way with any mover), the flow, the structure and the mover by slabs.
"""
