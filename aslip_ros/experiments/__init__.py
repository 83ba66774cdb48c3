"""aslip_ros.experiments."""
