"""What a hostile or broken peer can do to a live agent: network cases, the ROS side, fuzzing."""
