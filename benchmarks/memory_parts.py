"""Where a one-way design iteration's memory goes on the iterative path, part by part.

Runs ``tofsi optimize`` of ``beam_in_channel_optimization`` in this process under
``tracemalloc`` (NumPy's and SciPy's arrays, pyamg's hierarchies: everything but the
interpreter and the libraries themselves), looks at the traced memory after every
preconditioner application of a Krylov solve (its basis is live then), every assembly and
every AMG setup, keeps a snapshot at the highest, and sorts what is live there by the
allocating code (the innermost frame of tofsi or pyamg) into parts; prints bytes per element
per part, with ``ru_maxrss`` of the whole process:

    python -m benchmarks.memory_parts [--elements-x 180] [--iterations 2] [--backend iterative]

(tracemalloc slows the run 1.5-2x; the peak it sees is the arrays', below ``ru_maxrss`` by
the interpreter and the libraries.)
"""

from __future__ import annotations

import argparse
import collections
import resource
import tempfile
import time
import tracemalloc
from pathlib import Path

SCENE = Path(__file__).resolve().parents[1] / "examples" / "scenes" / "beam_in_channel_optimization.toml"

PARTS = [      # (part, a substring of the allocating frame "file:function"), first match wins
    ("Krylov basis (FGMRES/GMRES/CG)", "krylov/"),
    ("Krylov basis (FGMRES/GMRES/CG)", "recycling.py:flexible_gmres"),
    ("Krylov basis (FGMRES/GMRES/CG)", "linalg/krylov.py"),
    ("AMG hierarchy (velocity, pressure, structure)", "pyamg/"),
    ("AMG hierarchy (velocity, pressure, structure)", "linalg/amg.py"),
    ("flow preconditioner: blocks and scaling", "iterative.py"),
    ("flow preconditioner: Schur parts", "flow_preconditioner.py"),
    ("assembly pattern slots", "assembly.py:_ensure_slots"),
    ("assembly pattern slots", "assembly.py:__init__"),
    ("assembled matrices (flow J, structure K, partials)", "assembly.py:zeros"),
    ("assembly pattern slots", "dirichlet.py:__init__"),
    ("assembled matrices (flow J, structure K, partials)", "assembly.py:assemble"),
    ("flow element residuals and Jacobians (kernel)", "fluid_kernel.py"),
    ("flow element residuals and Jacobians (kernel)", "fluid_elements.py"),
    ("fluid load (reaction parts, partials)", "fluid_load.py"),
    ("structure (element data, partials)", "structure.py"),
    ("design map and filter", "design.py"),
    ("kept-evaluation keys", "kept.py"),
    ("mesh and maps", "mesh.py"),
    ("flow (state, Newton, dofs)", "physics/flow.py"),
]


def part_of(trace) -> str:
    for frame in reversed(trace.traceback):            # the most recent call first
        for name, key in PARTS:
            file_key, _, function = key.partition(":")
            if file_key in frame.filename:
                if not function or function in _function_name(frame):
                    return name
    return "other"


_LINES: dict = {}


def _function_name(frame) -> str:
    """The name of the function a frame is in (from the source: tracemalloc keeps lines only)."""
    import linecache
    key = (frame.filename, frame.lineno)
    if key not in _LINES:
        name = ""
        for n in range(frame.lineno, 0, -1):
            line = linecache.getline(frame.filename, n).lstrip()
            if line.startswith("def "):
                name = line[4:].split("(")[0]
                break
        _LINES[key] = name
    return _LINES[key]


class PeakSampler:
    """Keeps a snapshot of the traced memory at its highest point among the moments it is
    asked to look (every Krylov preconditioner application, every assembly): a new snapshot
    when the traced memory is 5 % above the last one's and above ``floor`` bytes (a snapshot
    costs seconds)."""

    def __init__(self, floor: float):
        self.best, self.snapshot = floor, None

    def look(self):
        current = tracemalloc.get_traced_memory()[0]
        if current > 1.05 * self.best:
            self.best = current
            self.snapshot = tracemalloc.take_snapshot()

    def watch(self, owner, name):
        function = getattr(owner, name)

        def watched(*a, **k):
            out = function(*a, **k)
            self.look()
            return out
        setattr(owner, name, watched)


def watch_points(sampler):
    """Look after every preconditioner application (the Krylov basis is live then), every
    matrix from a pattern, every AMG setup."""
    import tofsi.linalg.recycling as recycling
    import tofsi.linalg.iterative as iterative
    from tofsi.fem.assembly import SparsePattern

    def looking(original):
        def krylov(A, b, apply, *a, **k):
            def looked(r):
                out = apply(r)
                sampler.look()
                return out
            return original(A, b, looked, *a, **k)
        return krylov
    for module in (recycling, iterative):
        for name in ("gmres", "flexible_gmres"):          # (the code before issue 34: FGMRES only)
            if hasattr(module, name):
                setattr(module, name, looking(getattr(module, name)))
    for name in ("matrix", "assemble"):
        if hasattr(SparsePattern, name):
            sampler.watch(SparsePattern, name)
    sampler.watch(iterative, "_amg")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements-x", type=int, default=180)
    ap.add_argument("--iterations", type=int, default=2)
    ap.add_argument("--backend", default="iterative")
    args = ap.parse_args(argv)
    h = 2.0 / args.elements_x
    from tofsi.cli import main as tofsi_main
    tracemalloc.start(12)
    sampler = PeakSampler(floor=8e3 * args.elements_x ** 2 / 2)          # 8 kB per element
    watch_points(sampler)
    t0 = time.process_time()
    with tempfile.TemporaryDirectory() as out:
        status = tofsi_main(["optimize", str(SCENE), "--set", f"mesh.h_min={h}", "--set", f"mesh.h_max={h}",
                             "--set", f"solver.linear_solver={args.backend}", "--set",
                             f"optimizer.max_iter={args.iterations}", "--output", out, "--quiet"])
    cpu = time.process_time() - t0
    peak_traced = tracemalloc.get_traced_memory()[1]
    E = (args.elements_x) * (args.elements_x // 2)
    sizes = collections.Counter()
    for trace in sampler.snapshot.traces:
        sizes[part_of(trace)] += trace.size
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(f"{E} elements, backend {args.backend}, status {status}, {cpu:.1f} s CPU; ru_maxrss {rss / 2**30:.3f} GiB "
          f"({rss / E / 1e3:.1f} kB per element), traced peak {peak_traced / 2**30:.3f} GiB "
          f"({peak_traced / E / 1e3:.1f} kB/el); at the sampled peak ({sum(sizes.values()) / 2**30:.3f} GiB):")
    for name, size in sizes.most_common():
        print(f"  {name:52s} {size / 2**20:9.1f} MiB {size / E / 1e3:7.2f} kB/el")


if __name__ == "__main__":
    main()
