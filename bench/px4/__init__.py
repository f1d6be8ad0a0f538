"""PX4 against the agent: its capture replayed at PX4's pace, and PX4 SITL itself."""
