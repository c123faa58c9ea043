"""ROS message decoding, shared by every ROS container and by live's payload decoder.

``read`` turns what a container collected into :class:`~imu_dcm.logio.types.LogData`;
``channels`` says which channels are the IMU and the truth; ``schema`` parses message
definitions, ``cdr`` decodes payloads in bulk with numpy, ``tf`` reads ``/tf``, ``json_imu``
JSON channels; ``payload`` decodes payloads that came from no file (live sources).
"""
