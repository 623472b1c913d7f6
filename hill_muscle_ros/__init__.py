"""hill_muscle_ros: a Hill-type FES muscle with motor-unit recruitment memory, for ROS 2."""
