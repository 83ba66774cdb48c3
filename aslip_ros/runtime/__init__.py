"""What node programs run on, apart from the nodes themselves (floor 3, rclpy).

``process``: a node executable's life as a process (:func:`process.run_node`: spin, signals,
shutdown, exit); ``launcher``: an executable's first code (signals blocked before any
thread starts); ``child``: a node executable started from a test, a benchmark or a script;
``qos``: every topic's QoS profile.
"""
