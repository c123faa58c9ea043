"""data_synth: rigid-body ground truth (Euler's equations), a synthetic gyro and a ROS 2 log writer."""
