"""The readers of each log container, one module (or, for MCAP, one package) a container.

Each module holds a class satisfying :class:`~imu_dcm.logio.source.LogSource` and is named by
one row of :data:`imu_dcm.logio.registry.READERS`. The ROS containers (``mcap``, ``rosbag2``,
``ros1``) only collect raw channels and share the rest (:mod:`imu_dcm.logio.ros`); ``ulog``,
``ardupilot`` and ``euroc`` convert their own records; ``foreign`` and ``lfs`` recognise a
format only to refuse it, naming the command that converts it.
"""
