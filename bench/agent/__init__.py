"""What the agent costs the robot's computer: CPU per message, a robot's load, at rest, memory, and
the floors and load generators those figures stand on."""
