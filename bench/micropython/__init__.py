"""The client on a board: its heap and speed under MicroPython."""
