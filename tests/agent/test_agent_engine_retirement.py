"""Agent engine: when a client is certainly gone ("Recovery and liveliness" in
docs/ARCHITECTURE.md), on the engine's hand-moved clock: a new key on a session's endpoint replaces
it at once; a dead client whose host brought a new client with its participant is retired; a dead
client whose serial port or TCP connection closed is retired; nothing else deletes a sleeper, for
10 minutes or any other time; ``client_expire_time`` counts from the last message, whatever the
dead time. The same rules through real sockets and rclpy: tests/recovery/test_recovery_liveness.py."""

from engine_peer import Clock, Link, Peer, data_of
from xrce.wire import constants as C
from xrce.agent.engine.agent import Agent
from xrce.agent.middleware.ced import CedMiddleware
from xrce.wire.submessages import DeliveryControl

OLD, NEW, OTHER = b"\x0b\x0b\x00\x01", b"\x0b\x0b\x00\x02", b"\x0c\x0c\x00\x03"


def engine(**options):
    agent = Agent(CedMiddleware(), **options)
    agent.clock = Clock()
    return agent, Link()


def board(agent, link, endpoint, key, name="p"):
    """A client with a participant called ``name`` (a node: what tells boards apart)."""
    peer = Peer(agent, link, endpoint, key=key)
    assert peer.connect()[1] == C.STATUS_OK
    peer.build_pubsub(participant=name)
    return peer


def test_a_new_key_on_the_same_endpoint_replaces_the_old_client_at_once(ced_agent):
    agent, link = ced_agent
    old = board(agent, link, ("10.0.0.5", 7400), OLD)
    assert OLD in agent.clients
    board(agent, link, ("10.0.0.5", 7400), NEW)  # the board rebooted, same address and port
    assert OLD not in agent.clients and NEW in agent.clients
    assert agent.stats.clients_replaced == 1
    assert not old.take()  # nothing more goes to the old session


def test_the_same_key_from_a_new_port_restarts_the_session_and_keeps_its_objects(ced_agent):
    """PX4's restart (golden px4_restart): key 00000001, session 0x81, a new UDP source port."""
    agent, link = ced_agent
    board(agent, link, ("10.0.0.5", 7400), OLD)
    objects = dict(agent.clients[OLD].objects)
    again = Peer(agent, link, ("10.0.0.5", 7401), key=OLD)
    assert again.connect()[1] == C.STATUS_OK
    assert agent.clients[OLD].objects == objects and agent.clients[OLD].endpoint[1] == 7401
    assert agent.stats.clients_replaced == agent.stats.clients_retired == 0


def test_a_new_key_from_the_same_host_retires_the_silent_old_one_after_its_dead_time(ced_agent):
    agent, link = ced_agent
    board(agent, link, ("10.0.0.5", 7400), OLD)
    born_old = agent.clock.now
    agent.clock.now += 1
    new = board(agent, link, ("10.0.0.5", 7555), NEW)  # rebooted: a new port and a new rand() key
    agent.clock.now = born_old + agent.client_dead_time - 0.01
    agent.tick()
    assert OLD in agent.clients  # not before the dead time: silence alone proves nothing sooner
    new.send(0, *[])  # the new board keeps talking (an empty message on stream 0)
    agent.clock.now = born_old + agent.client_dead_time
    agent.tick()
    assert OLD not in agent.clients and NEW in agent.clients
    assert agent.stats.clients_retired == 1


def test_boards_behind_one_address_do_not_retire_each_other(ced_agent):
    """Two boards behind one NAT address: each new client (a reboot of one, or a stranger's
    CREATE_CLIENT from that address) retires nothing while the others speak, nor a dead
    neighbour that is another node (another participant)."""
    agent, link = ced_agent
    talking = board(agent, link, ("10.0.0.9", 1000), OLD, name="talker")
    sleeping = board(agent, link, ("10.0.0.9", 1001), OTHER, name="sleeper")
    for life in range(5):
        agent.clock.now += agent.client_dead_time / 2
        talking.write(b"alive")
        key = bytes([0x0d, 0, 0, life + 1])
        board(agent, link, ("10.0.0.9", 2000 + life), key, name="reboot%d" % life)
        agent.tick()
    assert OLD in agent.clients and OTHER in agent.clients
    assert agent.clients[OTHER].dead and agent.stats.clients_retired == 0
    # The sleeper wakes: its session is all there.
    sleeping.write(b"back")
    assert not agent.clients[OTHER].dead


def test_a_sleeper_keeps_its_session_for_ten_minutes_and_publishes_after(ced_agent):
    agent, link = ced_agent
    sleeper = board(agent, link, ("10.0.0.7", 1000), OLD)
    listener = board(agent, link, ("10.0.0.8", 1000), OTHER)
    listener.read(0x80, DeliveryControl())
    listener.take()
    for _ in range(20):  # ten minutes, the tick every 30 s that a timer would bring
        agent.clock.now += 30
        agent.tick()
        listener.ack_all()
    assert OLD in agent.clients and agent.clients[OLD].dead
    sleeper.write(b"good morning")
    assert data_of(listener.take()) == [b"good morning"]
    assert agent.stats.clients_retired == agent.stats.clients_expired == 0


def test_expiry_counts_from_the_last_message_whatever_the_dead_time():
    agent, link = engine(client_expire_time=3.0)  # dead time: the default 30 s
    peer = board(agent, link, ("10.0.0.5", 7400), OLD)
    last = agent.clock.now
    agent.clock.now = last + 2.99
    agent.tick()
    assert OLD in agent.clients
    agent.clock.now = last + 3.0
    agent.tick()
    assert OLD not in agent.clients and agent.stats.clients_expired == 1
    assert agent.stats.clients_dead == 0  # deleted before it was ever dead
    del peer


def test_a_closed_endpoint_is_replaced_at_once_or_retired_after_the_dead_time(ced_agent):
    """A serial board re-enumerating: its port closes and opens again at the same name; a new
    key there replaces the old session at once. A port that never comes back: retired."""
    agent, link = ced_agent
    board(agent, link, ("/dev/ttyACM0", 0), OLD)
    agent.endpoint_closed(link, ("/dev/ttyACM0", 0))
    assert OLD in agent.clients  # the same board may come back with its key (REUSE)
    board(agent, link, ("/dev/ttyACM0", 0), NEW)
    assert OLD not in agent.clients and agent.stats.clients_replaced == 1

    board(agent, link, ("/dev/ttyUSB1", 0), OTHER)
    agent.endpoint_closed(link, ("/dev/ttyUSB1", 0))
    agent.clock.now += agent.client_dead_time
    agent.tick()
    assert OTHER not in agent.clients and agent.stats.clients_retired == 1


def test_a_spoofed_create_client_cannot_retire_a_live_board(ced_agent):
    """A stranger who can send from the board's address and copies its participant: the board
    is retired only if it has been silent for the dead time since; one that speaks stays."""
    agent, link = ced_agent
    live = board(agent, link, ("10.0.0.5", 7400), OLD)
    for i in range(3):
        board(agent, link, ("10.0.0.5", 9000 + i), bytes([0x66, 0, 0, i + 1]))  # same participant
        agent.clock.now += agent.client_dead_time - 1
        live.write(b"still here")
        agent.tick()
    assert OLD in agent.clients
    # Each stranger's session, silent since, was the one retired by the next.
    assert agent.stats.clients_retired == 2 and list(agent.clients) == [OLD, b"\x66\x00\x00\x03"]


def test_a_board_reconnecting_under_new_keys_leaves_the_lives_of_one_dead_time(ced_agent):
    """rmw_microxrcedds' reconnection, once a second, 100 times, with the agent's defaults: at
    any time at most the lives heard within the dead time (30 s) are there, then only the last."""
    agent, link = ced_agent
    most = 0
    for life in range(100):
        peer = board(agent, link, ("10.0.0.5", 40000 + life), bytes([0x0e, 0, life, 1]))
        peer.write(b"odom")
        agent.clock.now += 1.0
        agent.tick()
        most = max(most, len(agent.clients))
    assert most <= agent.client_dead_time + 1
    agent.clock.now += agent.client_dead_time
    agent.tick()
    # The last life stays: asleep, as far as anyone can tell.
    assert list(agent.clients) == [bytes([0x0e, 0, 99, 1])]
    assert agent.stats.clients_retired == 99
