"""Core records of every floor: errors, configuration records, the registries, the block protocol, kept evaluations and iteration helpers."""
