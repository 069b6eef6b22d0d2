"""The toolkit's version (as ``pyproject.toml`` states it): ``tofsi.__version__``, run records."""

VERSION = "0.1.0"
