"""Benchmarks and studies of imu_dcm: speed against accuracy, stability, noise.

Run from the repository root: ``python -m benchmarks``.
"""
