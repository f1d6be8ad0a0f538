"""Boards that reboot, reconnect and vanish, and many boards at once."""
