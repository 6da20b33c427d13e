"""Measured data: readers, pre-processing, datasets, the loss and synthetic data."""
