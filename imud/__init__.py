"""imud: IMU acquisition daemon publishing calibrated, timestamped samples over Eclipse Zenoh."""

__version__ = "0.1.0"
