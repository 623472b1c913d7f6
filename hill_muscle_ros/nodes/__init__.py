"""ROS 2 nodes: thin shells that translate between topics and the model core."""
