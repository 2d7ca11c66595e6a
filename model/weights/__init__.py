"""Shipped weights (safetensors) and their model cards."""
