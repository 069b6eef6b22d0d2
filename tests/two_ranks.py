"""Running a script on two MPI ranks from the tests, or skipping with the reason.

Shared by ``tests/test_parallel.py`` (the flow by slabs) and ``tests/test_parallel_fsi.py``
(the two-way problem and the movers by slabs).
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def petsc_or_skip():
    try:
        import petsc4py  # noqa: F401
    except ImportError as err:
        pytest.skip(f"petsc4py does not import ({err}): see docs/parallel.md")
    mpiexec = shutil.which("mpiexec")
    if mpiexec is None:
        pytest.skip("mpiexec not found")
    return mpiexec


def run_on_two_ranks(script: str, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    """``mpiexec -n 2 python script args`` from the repository root, as root if need be."""
    mpiexec = petsc_or_skip()
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMPI_MCA_rmaps_base_oversubscribe": "1",
           "OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1"}
    return subprocess.run([mpiexec, "-n", "2", sys.executable, script, *args], cwd=ROOT, env=env, check=check,
                          timeout=300, capture_output=not check, text=True)
