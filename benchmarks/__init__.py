"""Benchmarks and studies of imu_dcm: speed against accuracy, stability, noise (`python -m benchmarks`)."""
