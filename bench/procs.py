"""Stopping the bench's child processes the way a user would: Ctrl-C first, kill only if it hangs."""

import signal
import subprocess


def interrupt(proc, timeout_s=10):
    """SIGINT ``proc`` (so agents destroy their ROS entities), wait, and kill it if it hangs."""
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
