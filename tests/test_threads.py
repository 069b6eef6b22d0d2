"""Threads are set deliberately: what the scene says, unless the environment says otherwise."""

from __future__ import annotations

import pytest
from threadpoolctl import threadpool_info

from tofsi.linalg import backends
from tofsi.settings import SolverSettings
from tofsi.threads import configure, set_blas_threads, solver_threads


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
        assert backends.default() == "auto"
        monkeypatch.setenv("TOFSI_LINEAR_SOLVER", "nonsense")
        with pytest.raises(Exception, match="solver.linear_solver"):
            configure(SolverSettings())
    finally:
        monkeypatch.delenv("TOFSI_LINEAR_SOLVER")
        configure(SolverSettings())
    assert backends.default() == "superlu"
