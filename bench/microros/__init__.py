"""A micro-ROS firmware against the agent: its entity set-up and its service replier, beside
eProsima's agent."""
