"""The package's one time-unit constant.

ROS time is integer nanoseconds (``builtin_interfaces/Time`` is ``sec`` plus
``nanosec``; rclpy clocks, rmw timestamps and MCAP log times count
nanoseconds); the model and the parameters count seconds (REP 103). Every
conversion between the two goes through :data:`NS_PER_S`. No imports: the
model core, the nodes, the recording code, tests and benchmarks all may use it.
"""

#: [ns/s] nanoseconds per second (exact, an int, so stamps stay exact integers).
NS_PER_S = 1_000_000_000
