"""The C heap's free pages given back to the system (glibc's ``malloc_trim``): by the engine once
start-up and bursts are over, by the ROS middleware once a domain's DDS participant is gone."""


def return_free_heap() -> None:
    """Give the C heap's free pages back to the system once start-up is over (glibc only).
    Through the agent's own tiny extension (``xrce/agent/_heap.c``) where it is built: the ctypes
    package, once imported, stays in the process (0.57 MB of classes)."""
    try:
        from xrce.agent._heap import return_free_heap
    except ImportError:
        try:
            import ctypes
            ctypes.CDLL(None).malloc_trim(0)
        except (ImportError, OSError, AttributeError):
            pass
    else:
        return_free_heap()
