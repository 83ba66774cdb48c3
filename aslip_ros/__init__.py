"""A-SLIP: acoustic in-hand slip sensing for ROS 2.

The package holds a ROS-free core (scene, data, learn, control, hw) and thin rclpy node
modules under ``aslip_ros.nodes``. The generated message module ``aslip_ros.msg`` exists only
in a colcon build of the package.
"""

__version__ = "0.1.0"
