"""A plain DDS program that is neither the agent nor ROS: Cyclone DDS's Python binding (PyPI
``cyclonedds``), run as a child process by tests/dds. Its type is its own, ``HelloWorld
{uint32 index; string message;}``; it reads ``<up topic>`` and writes ``<down topic>`` every
100 ms, one line per event on stdout:

- ``down <index> <hex>``: a sample it wrote, with its serialized body (after the 4-byte header);
- ``up <index> <message>``: a sample it read;

until stdin closes. Usage: ``cyclone_peer.py DOMAIN UP_TOPIC DOWN_TOPIC``."""

import sys
import threading
import time
from dataclasses import dataclass

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic


@dataclass
class HelloWorld(IdlStruct, typename="HelloWorld"):
    index: uint32
    message: str


def main():
    domain, up_name, down_name = int(sys.argv[1]), sys.argv[2], sys.argv[3]
    participant = DomainParticipant(domain)
    qos = Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(16))
    reader = DataReader(participant, Topic(participant, up_name, HelloWorld), qos=qos)
    writer = DataWriter(participant, Topic(participant, down_name, HelloWorld), qos=qos)
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    index = 0
    while not stop.is_set():
        for sample in reader.take(16):
            print("up", sample.index, sample.message, flush=True)
        index += 1
        sample = HelloWorld(index, "cyclone says %d" % index)
        writer.write(sample)
        print("down", index, sample.serialize()[4:].hex(), flush=True)
        time.sleep(0.1)


if __name__ == "__main__":
    main()
