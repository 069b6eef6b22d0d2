"""Reference-element machinery shared by every physics kernel and mover."""
