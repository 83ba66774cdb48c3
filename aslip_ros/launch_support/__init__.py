"""The logic of the launch files in ``launch/`` (floor 3: ``launch``, ``launch_ros``).

``common``: what every launch file shares (the cell file and the hardware launch arguments,
rviz, failing a launch with exit code 1); ``closed_loop``: the closed-loop graph of a
controller (slip_stop.launch.py, slip_track.launch.py); ``rviz_view``: the rviz
configuration of a graph (ROS-free).
"""
