"""The integrator: gyro rates to attitude by the DCM recursion ``R ← R · exp(φ×)``.

- :mod:`~imu_dcm.integrator.methods`: the method names and their orders (no numpy);
- :mod:`~imu_dcm.integrator.batch`: :func:`integrate` and :func:`integrate_delta` over a whole
  array, gap detection and the input checks;
- :mod:`~imu_dcm.integrator.streaming`: :class:`DcmIntegrator`, the same kernel sample by sample;
- :mod:`~imu_dcm.integrator.reference`: the plain textbook loops the benchmarks compare against;
- :mod:`~imu_dcm.integrator.peers`: other libraries' integrators behind one signature.

The compiled loop they share is in :mod:`imu_dcm._kernels`. ``imu_dcm.integrate`` and the other
names of the top-level package load from here on first use.
"""
