"""Physics: elasticity, Taylor-Hood and equal-order flow, the fluid load, mesh motion, material interpolations."""
