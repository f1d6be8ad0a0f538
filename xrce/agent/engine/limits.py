"""The engine's limits: stream depth, the per-client quotas and memory budget, the session timings."""

from dataclasses import dataclass
from typing import Optional

STREAM_WINDOW = 16  # RELIABLE_STREAM_DEPTH of the eProsima agent, both directions
# Per-client quotas (defaults; ``Agent`` takes each as a constructor argument, the CLI as a flag).
# A fragmented message larger than this is abandoned: room for a 1 MiB sample (camera frames,
# point clouds) and its headers.
MAX_REASSEMBLY = 1024 * 1024 + 1024
MAX_OBJECTS_PER_CLIENT = 4096  # beyond this CREATE answers ERR_RESOURCES
MAX_OUTPUT_QUEUE_BYTES = 1024 * 1024  # samples waiting for one client; the oldest go first
MAX_CLIENTS = 1024  # CREATE_CLIENT of a new key beyond this evicts a dead or idle client
# Memory budget: every buffer a client can fill (out-of-order input, reassembly, parked messages,
# reader queues, reliable output windows and fragments waiting for them) counts against its own
# budget and against the agent's total. Past either, buffered input is refused unacknowledged
# (the client retransmits later) and output for that client is dropped; the agent goes on.
MAX_CLIENT_BYTES = 8 * 1024 * 1024
MAX_TOTAL_BYTES = 64 * 1024 * 1024
TRIM_AFTER_BYTES = 256 * 1024  # a client deleted holding more: free heap pages go back (malloc_trim)
QUOTA_LOG_INTERVAL = 1.0  # seconds between repeated quota log lines for one client and quota
# eProsima's UAGENT_CONFIG_CLIENT_DEAD_TIME; eProsima never destroys a silent client's entities
# unless it asked for hard liveliness (uxr_hl), hence expiry off by default.
CLIENT_DEAD_TIME = 30.0
CLIENT_EXPIRE_TIME = 0.0
MIN_MTU = 24  # smaller CREATE_CLIENT mtu values would leave no room for a fragment chunk
DEFAULT_MTU = 508  # what eProsima assumes when CREATE_CLIENT carries none
INFO_CACHE_SIZE = 256  # encoded INFO replies kept (a ping repeats one question)
# After a new client appears on a host, how long (s) its dead neighbours are checked, and how
# often, for the participant that would show it to be one of them started over.
SUCCESSOR_WATCH_S = 60.0
SUCCESSOR_CHECK_S = 0.5


@dataclass(frozen=True)
class DataLimits:
    """What one client's samples may hold in the data path (``DataPath``): a reassembly
    (``max_reassembly_bytes``, None for ``MAX_REASSEMBLY``, looked up when used) and the samples
    queued for its readers (``max_output_queue_bytes``)."""

    max_reassembly_bytes: Optional[int] = None
    max_output_queue_bytes: int = MAX_OUTPUT_QUEUE_BYTES
