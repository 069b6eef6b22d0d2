"""Design optimization: the design map, the design problem, the optimizer and its stages, checkpoints, tuning and studies."""
