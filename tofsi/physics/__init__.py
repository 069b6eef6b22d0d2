"""Physics kernels and residual blocks: elasticity, Taylor-Hood flow, fluid load."""
