"""Coverage-guided fuzzing of the agent engine with atheris (libFuzzer), bounded by default.

    python bench/atheris_engine.py [-runs=200000] [libFuzzer options]

Each input is split into messages (first byte = length) fed to an in-process ``Agent`` (CED
middleware) from an endpoint that already holds a session, so the session, stream, fragment and
object paths are reachable; any exception escaping ``Agent.receive`` or ``tick`` is a finding.
"""

import sys
from pathlib import Path

import atheris

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

with atheris.instrument_imports():
    from xrce.agent.ced import CedMiddleware
    from xrce.agent.engine import Agent
    from xrce.submessages import CreateClient, encode_message


class _Link:
    name = "atheris"

    def send(self, endpoint, data):
        return True


CREATE_CLIENT = encode_message(0x80, 0, 0, None, [CreateClient(b"\x01\x02\x03\x04", 0x81, 508)])


def one_input(data):
    agent = Agent(CedMiddleware(), max_clients=4)
    link = _Link()
    agent.receive(link, ("fuzz", 1), CREATE_CLIENT)
    position = 0
    while position < len(data):
        size = data[position]
        message = data[position + 1:position + 1 + size]
        position += 1 + size
        agent.receive(link, ("fuzz", 1), message)
    agent.tick()
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
