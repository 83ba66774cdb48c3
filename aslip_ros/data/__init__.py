"""Data layer (ROS-free): rosbag2 I/O, slip labels, the on-disk dataset, export, simulation.

Modules: ``bags`` (message types, BagWriter, BagReader), ``labels`` (ground truth),
``dataset`` (DatasetWriter, Dataset, split_trials), ``export`` (``aslip export``),
``simulate`` (``aslip simulate``), ``presets`` (``make datasets``), ``synthetic`` (bags with
known slip for tests and benchmarks). See docs/data.md. Nothing is imported here so that
``import aslip_ros.data`` stays cheap.
"""
