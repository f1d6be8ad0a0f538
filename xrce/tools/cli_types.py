"""argparse value types that both command lines (xrce-agent, xrce-client) take."""

import argparse


def domain_id(text):
    """A ROS domain id, as ROS_DOMAIN_ID or --domain gives it."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError("invalid domain id: %r" % text)
    if not 0 <= value <= 232:  # the largest id whose RTPS ports still fit in 16 bits
        raise argparse.ArgumentTypeError("domain id %d is not in 0..232" % value)
    return value
