"""The coupled model: block systems, the coupled solve and its load ramp, prescribed deformations and mesh-motion runs."""
