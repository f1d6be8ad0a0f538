"""What a set-up client session allocates per sample on a board, measured under real MicroPython
1.27 (WebAssembly) against a real xrce-agent over the real UdpTransport and the harness' port-like
socket (tests/micropython/session_alloc.py; issue 32).

Nothing per sample published, best-effort or reliable (the reliable history keeps the buffer each
message was built in, no copy), and nothing per sample received when the reader decodes into a
preallocated message (create_reader's ``into``), acknowledgements and heartbeats included: the only
garbage left is what the socket's recv allocates for each datagram, which the socket shim counts
and the script subtracts. builtin_interfaces/Time is the sample: integers, which a 32-bit port
holds without allocating (a float is an object of its own on a board, whoever decodes it).
"""

from pathlib import Path

import pytest

from agent_process import AgentProcess
from mp_harness import run_micropython
from xrce.wire.stream_payloads import TimestampReply
from xrce.wire.submessages import decode_message

SCRIPT = Path(__file__).resolve().parents[1] / "micropython" / "session_alloc.py"
COUNT = 20


@pytest.mark.timeout(240)
def test_a_set_up_session_allocates_nothing_per_sample_published_or_received():
    with AgentProcess("udp4", "-m", "ced") as agent:
        result = run_micropython(SCRIPT, agent.port, COUNT, timeout=200)
    assert result.returncode == 0, (result.stdout, result.stderr)
    lines = dict(line.split(" ", 1) for line in result.stdout.splitlines() if " " in line)
    print({key: value for key, value in lines.items() if key.endswith("_bytes")})
    assert lines["create"] == lines["setup"] == lines["done"] == "True", result.stdout
    for key in ("publish_best_effort", "publish_reliable", "receive_best_effort", "receive_reliable",
                "time_sync", "ping"):
        assert int(lines[key + "_bytes"]) == 0, (key, result.stdout)
    assert lines["time_synced"] == lines["offset_sync"] == "True", result.stdout
    _assert_offset_is_the_ns_formula(lines)
    # The samples did go round (warm-up 8, then COUNT) and were decoded into the preallocated
    # messages: the last one carried COUNT - 1.
    assert lines["received"] == "%d %d" % (8 + COUNT, 8 + COUNT), result.stdout
    assert lines["last"] == "%d %d" % (COUNT - 1, COUNT - 1), result.stdout
    # The socket's own: at least one datagram per sample received (and the measurement is real).
    assert int(lines["receive_reliable_socket_bytes"]) >= COUNT * 513, result.stdout
    assert lines["dropped_writes"] == "0", result.stdout


def _assert_offset_is_the_ns_formula(lines):
    # The board's offset, worked out without big integers, against the nanosecond formula CPython
    # computes from the same exchange: the agent's reply (the one that answered the stamp sent)
    # and the client's originate and receive stamps.
    t0, t3 = int(lines["offset_t0_ns"]), int(lines["offset_t3_ns"])
    stamps = [payload for reply in lines["offset_replies"].split()
              for payload in decode_message(bytes.fromhex(reply))[1]
              if isinstance(payload, TimestampReply) and payload.originate_ns == t0]
    assert len(stamps) == 1, lines
    t1, t2 = stamps[0].receive_ns, stamps[0].transmit_ns
    twice = (t0 + t3) - (t1 + t2)
    assert int(lines["offset_ns"]) == (-((-twice) // 2) if twice < 0 else twice // 2), lines
    assert int(lines["offset_rtt_ns"]) == max(0, (t3 - t0) - (t2 - t1)), lines
    # Agent and client share this machine's clock: the offset is within the round trip, give or
    # take the harness clocks' millisecond steps.
    assert abs(int(lines["offset_ns"])) <= int(lines["offset_rtt_ns"]) + 10 * 10**6, lines
