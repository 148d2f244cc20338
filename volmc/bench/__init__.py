"""Benchmarks: named configurations that print their cost (and, later, error) side by side."""
