"""Threads are set deliberately: what the scene says, unless the environment says otherwise."""

from __future__ import annotations

import pytest
from threadpoolctl import threadpool_info

from tofsi.linalg import backends
from tofsi.scene.settings import SolverSettings
from tofsi.linalg.threads import configure, set_blas_threads, solver_threads


def openblas_threads() -> set[int]:
    return {i["num_threads"] for i in threadpool_info() if i["internal_api"] == "openblas"}


def test_blas_threads_limit_every_openblas(monkeypatch):
    monkeypatch.delenv("TOFSI_BLAS_THREADS", raising=False)
    try:
        assert set_blas_threads(2) == 2 and openblas_threads() == {2}
        assert set_blas_threads(1) == 1 and openblas_threads() == {1}
        assert set_blas_threads(0) is None and openblas_threads() == {1}     # 0: left alone
        monkeypatch.setenv("TOFSI_BLAS_THREADS", "2")
        assert set_blas_threads(1) == 2 and openblas_threads() == {2}        # the environment wins
    finally:
        monkeypatch.delenv("TOFSI_BLAS_THREADS", raising=False)
        set_blas_threads(1)


def test_solver_threads_default_to_the_cores(monkeypatch):
    import os
    monkeypatch.delenv("TOFSI_THREADS", raising=False)
    assert solver_threads(0) == (os.cpu_count() or 1)
    assert solver_threads(3) == 3
    monkeypatch.setenv("TOFSI_THREADS", "1")
    assert solver_threads(3) == 1


def test_environment_overrides_the_scene_backend(monkeypatch):
    monkeypatch.setenv("TOFSI_LINEAR_SOLVER", "auto")
    try:
        configure(SolverSettings(linear_solver="superlu"))
        assert backends.default() == backends.available()[0]          # auto: the fastest installed
        monkeypatch.setenv("TOFSI_LINEAR_SOLVER", "nonsense")
        with pytest.raises(Exception, match="solver.linear_solver"):
            configure(SolverSettings())
    finally:
        monkeypatch.delenv("TOFSI_LINEAR_SOLVER")
        configure(SolverSettings())
    assert backends.default() == "superlu"


def test_two_models_with_different_solver_tables_do_not_interfere(monkeypatch):
    """Building a model changes nothing process-wide: each solves with its own BLAS threads and
    backend, whichever was built last."""
    import tofsi
    from tofsi.coupling.coupled import CoupledModel
    monkeypatch.delenv("TOFSI_BLAS_THREADS", raising=False)
    monkeypatch.delenv("TOFSI_LINEAR_SOLVER", raising=False)
    base = ["mesh.h_min=0.1", "mesh.h_max=0.1"]
    path = "examples/scenes/beam_in_channel_optimization.toml"
    set_blas_threads(1)
    default = backends.default()
    a = CoupledModel(tofsi.load_scene(path, base + ["solver.blas_threads=1"]))
    b = CoupledModel(tofsi.load_scene(path, base + ["solver.blas_threads=2", "solver.threads=2",
                                                    "solver.linear_solver=auto"]))
    assert backends.default() == default and openblas_threads() == {1}      # nothing global moved
    assert a.linear_algebra.blas_threads == 1 and b.linear_algebra.blas_threads == 2
    seen = {}
    for name, model in (("a", a), ("b", b), ("a again", a)):
        system_for = model.system_for

        def spy(params, system_for=system_for, name=name):
            seen[name] = openblas_threads()
            return system_for(params)
        monkeypatch.setattr(model, "system_for", spy)
        state = model.solve(model.densities())
        assert state.u is not None
    assert seen == {"a": {1}, "b": {2}, "a again": {1}} and openblas_threads() == {1}
    assert a.flow.linear_algebra.backend == "superlu" == a.structure.linear_algebra.backend
    assert b.flow.linear_algebra.backend == backends.available()[0]
    factor = a.flow.factorize(a.flow.jacobian(a.flow.initial())[0])
    assert factor.backend.name == "superlu"
