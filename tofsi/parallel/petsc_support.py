"""PETSc pieces of the distributed flow: the lazy import, the clean-up of dropped objects and
the pressure split's Python preconditioner (the Cahouet-Chabard approximation
``-S~^{-1} = M_mu^{-1} + L_alpha^{-1}``, see :mod:`tofsi.parallel.flow_system`)."""

from __future__ import annotations


def petsc():
    """petsc4py's PETSc module, imported when first needed (an optional extra)."""
    from petsc4py import PETSc
    return PETSc


def collect_garbage(comm) -> None:
    """Destroy the PETSc objects Python has dropped (collective on ``comm``).

    petsc4py >= 3.18 does not destroy an object on a parallel communicator when its
    Python reference goes (the ranks could disagree on when that happens): it parks it
    until ``PETSc.garbage_cleanup(comm)``. Without this call every flow solve's
    submatrices, Schur pieces, hierarchies and work vectors stay allocated -- 10 MB per
    two-way sweep at 2500 elements per rank, the per-rank peak growing with the sweeps."""
    cleanup = getattr(petsc(), "garbage_cleanup", None)        # absent before petsc4py 3.18
    if cleanup is not None:
        cleanup(comm)


class DarcySchurPC:
    """Python PC on the pressure split: ``y = -(g / M_mu + AMG(L_alpha) g)``."""

    def __init__(self, mass, L, amg: str):
        PETSc = petsc()
        self.inverse_mass = mass.copy()
        self.inverse_mass.reciprocal()
        self.inner = PETSc.PC().create(comm=L.getComm())
        self.inner.setOperators(L, L)
        self.inner.setType(amg)
        self.inner.setUp()
        self.work = L.createVecLeft()

    def apply(self, pc, g, y):
        self.inner.apply(g, self.work)
        y.pointwiseMult(g, self.inverse_mass)
        y.axpy(1.0, self.work)
        y.scale(-1.0)

    def applyTranspose(self, pc, g, y):        # noqa: N802 - PETSc's name; both terms are symmetric
        self.apply(pc, g, y)
