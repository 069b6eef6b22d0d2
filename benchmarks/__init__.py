"""Speed and accuracy measurements of tofsi; each module runs as ``python -m benchmarks.<name>``
(or ``python benchmarks/<name>.py``) from the repository root. Results: ``benchmarks/README.md``."""
