"""How long ROS goes dark when an agent or a board restarts, and how soon either side discovers the
other."""
