"""ROS 2 output: sensor_msgs on rmw_zenoh, through zenoh-bridge-ros2dds, or on DDS, with no ROS
installation (docs/ros2.md)."""
