"""What the gyro signal itself shows, before and around integration.

- :mod:`~imu_dcm.gyro.rates`: the implausible-rate rule and the unit evidence (replay and live);
- :mod:`~imu_dcm.gyro.rest`, :mod:`~imu_dcm.gyro.rest_evidence`, :mod:`~imu_dcm.gyro.windows`:
  the one rest rule (offline and causal) and the bias it gives;
- :mod:`~imu_dcm.gyro.stamps`: sample stamps (rate, order, units);
- :mod:`~imu_dcm.gyro.resample`: the truth slerp onto the gyro's stamps;
- :mod:`~imu_dcm.gyro.allan`: Allan deviation and the noise parameters;
- :mod:`~imu_dcm.gyro.prefilter`: the filterpy pre-filter of the rates.

None of it reads logs or draws: log I/O, replay and live import it, never the reverse.
"""
