"""Readers of measured curves, one module per file format."""
