"""Coverage-guided fuzzing of the agent engine with atheris (libFuzzer), bounded by default.

    python bench/hostile/atheris_engine.py [-runs=200000] [libFuzzer options]

Each input is split into messages (first byte = length) fed to an in-process ``Agent`` (CED
middleware) from an endpoint that already holds a session, so the session, stream, fragment and
object paths are reachable; any exception escaping ``Agent.receive`` or ``tick`` is a finding, and so
is memory budget accounting that does not add up. Topics of types starting "s" park their client
until a message starting with a zero byte ends the build (a parked client, held-back input).
"""

import sys
from pathlib import Path

import atheris

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the checkout, for xrce

with atheris.instrument_imports():
    from xrce.agent.middleware.ced import CedMiddleware
    from xrce.agent.engine.agent import Agent
    from xrce.wire.submessages import CreateClient, encode_message


class _ParkingMiddleware(CedMiddleware):
    """CED whose topics with a type name starting "s" wait for a build that ends at the next
    tick: the fuzzer reaches parked clients, and the reliable input held back behind them."""

    def __init__(self):
        super().__init__()
        import concurrent.futures
        self.build = concurrent.futures.Future()

    def create_topic(self, key, participant, topic):
        if topic.type_name.startswith("s") and not self.build.done():
            from xrce.agent.middleware import TypeNotReady
            raise TypeNotReady("being built", self.build)
        return super().create_topic(key, participant, topic)


class _Link:
    name = "atheris"
    sends_from_any_thread = False
    fastpath = None
    info_locators = ()

    def send(self, endpoint, data):
        return True


CREATE_CLIENT = encode_message(0x80, 0, 0, None, [CreateClient(b"\x01\x02\x03\x04", 0x81, 508)])


def one_input(data):
    middleware = _ParkingMiddleware()
    # A small budget, so that inputs reach it (out-of-order stores, long FRAGMENT chains).
    agent = Agent(middleware, max_clients=4, max_client_bytes=64 * 1024, max_total_bytes=128 * 1024)
    link = _Link()
    agent.receive(link, ("fuzz", 1), CREATE_CLIENT)
    position = 0
    while position < len(data):
        size = data[position]
        message = data[position + 1:position + 1 + size]
        position += 1 + size
        agent.receive(link, ("fuzz", 1), message)
        if message[:1] == b"\x00":  # now and then the build ends in the middle of the input
            if not middleware.build.done():
                middleware.build.set_result(None)
            agent.tick()
    agent.tick()
    total = sum(c.buffered for c in agent.clients.values())
    if total != agent.buffered_total:
        raise AssertionError("memory budget accounting: %d held, %d counted" %
                             (total, agent.buffered_total))
    if agent.stats.handler_errors:
        raise AssertionError("a handler raised: %r" % agent.stats.as_dict())


def main():
    argv = list(sys.argv)
    if not any(arg.startswith("-runs=") for arg in argv[1:]):
        argv.append("-runs=200000")
    atheris.Setup(argv, one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
