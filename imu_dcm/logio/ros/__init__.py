"""ROS message decoding, shared by every ROS container and by live's payload decoder.

``collect`` holds the raw form a container hands over (channels, payloads, the sink that
decodes them batch by batch); ``channels`` says which channels can be the IMU or the truth and
decodes them into columns; ``imu`` and ``truth`` pick among them; ``read`` turns what a
container collected into :class:`~imu_dcm.logio.types.LogData`. Below them: ``schema`` parses
message definitions, ``cdr`` decodes payloads in bulk with numpy, ``tf`` reads ``/tf``,
``json_imu`` JSON channels; ``payload`` decodes payloads that came from no file (live sources).
"""
