"""Scenes: the scene file's tables and records, loading, overrides and the generated reference."""
