"""One module per ``tofsi`` subcommand; each exposes ``run(scene, args, ctx) -> dict``."""
