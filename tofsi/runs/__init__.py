"""Runs and their output: files, pictures, provenance, the output folder and its lock, the memory and output-size guards."""
