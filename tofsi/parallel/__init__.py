"""Distributed assembly and solves under MPI with PETSc (optional: see ``docs/parallel.md``).

* :class:`~tofsi.parallel.partition.SlabPartition` -- element slabs by rank and the
  contiguous dof numbering;
* :class:`~tofsi.parallel.flow_system.DistributedFlow` -- the flow's Newton solve with
  each rank assembling only its slab, FGMRES with a Schur fieldsplit (GAMG or hypre).
"""
