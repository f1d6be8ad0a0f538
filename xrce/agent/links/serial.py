"""The agent's serial links: XRCE stream framing (§11) over serial devices and pseudoterminals.

The link contract is in ``xrce.agent.links``.
"""

from __future__ import annotations

import asyncio
import glob
import os
import termios
import tty

from xrce.agent.links import DEFAULT_BAUDRATE, MAX_PENDING_OUTPUT, Link, log
from xrce import EncodeError
from xrce.transports.crc import get_crc
from xrce.transports.framing import MAX_FRAME_PAYLOAD, FrameDecoder, encode_frame

SERIAL_AGENT_ADDRESS = 0
DEFAULT_REOPEN_INTERVAL = 0.2  # seconds between attempts to reopen a vanished serial device
_READ_CHUNK = 65536


class _FramedPort:
    """One open byte-stream fd with its own frame decoder and bounded output queue."""

    def __init__(self, name, fd, crc, closer):
        self.name = name
        self.fd = fd
        self.decoder = FrameDecoder(local_addr=SERIAL_AGENT_ADDRESS, max_payload=MAX_FRAME_PAYLOAD,
                                    crc=crc)
        self.pending = bytearray()
        self.writer_armed = False
        self.closer = closer
        self.open = True
        self.remotes = set()

    def dropped_frames(self):
        d = self.decoder
        return d.crc_errors + d.oversize + d.resyncs + d.wrong_address


class SerialFramedLink(Link):
    """XRCE stream framing (§11) over one or more byte-stream fds; the agent's address is 0.

    Endpoint = ``(port_name, remote_address)``; replies are framed src=0, dst=remote_address.
    Subclasses open the fds (``SerialServer``: pyserial ports; ``PseudoterminalServer``: a pty).
    """

    name = "serial"
    undecodable_what = "frames with a bad CRC or framing"

    def undecodable_advice(self):
        baudrate = getattr(self, "baudrate", None)
        return ("the board must use the same baud rate%s and CRC (--crc %s; eProsima and micro-ROS "
                "use arc), and send XRCE serial framing" % (
                    " (-b %d)" % baudrate if baudrate else "", self.crc_name))

    def __init__(self, receiver, *, crc="arc"):
        super().__init__(receiver)
        self.crc_name = crc if isinstance(crc, str) else getattr(crc, "__name__", "custom")
        self._crc = get_crc(crc)
        self.ports = {}
        self._loop = None

    def _add_port(self, name, fd, closer):
        self._loop = asyncio.get_running_loop()
        os.set_blocking(fd, False)
        port = _FramedPort(name, fd, self._crc, closer)
        self.ports[name] = port
        self._loop.add_reader(fd, self._on_readable, port)
        return port

    def _on_readable(self, port):
        try:
            data = os.read(port.fd, _READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            # EIO: the device went away (USB unplugged, pty peer gone for good).
            log.warning("%s: reading %s failed: %s; closing it", self.name, port.name, exc)
            self._close_port(port)
            return
        if not data:
            log.warning("%s: %s reached end of file; closing it", self.name, port.name)
            self._close_port(port)
            return
        self.stats.bytes_in += len(data)
        before = port.dropped_frames()
        frames = port.decoder.feed(data)
        dropped = port.dropped_frames() - before
        self.stats.drops += dropped
        if dropped and not frames:
            self.undecodable.bad(dropped, where=port.name)
        for src, _dst, payload in frames:
            endpoint = (port.name, src)
            port.remotes.add(src)
            self._deliver(endpoint, payload)

    def send(self, endpoint, data):
        try:
            port_name, remote = endpoint
            port = self.ports[port_name]
        except (KeyError, TypeError, ValueError):
            self.stats.drops += 1
            return False
        if not port.open:
            self.stats.drops += 1
            return False
        try:
            frame = encode_frame(data, SERIAL_AGENT_ADDRESS, remote, crc=self._crc)
        except EncodeError as exc:
            self.stats.drops += 1
            log.warning("%s: cannot frame a %d-byte message: %s", self.name, len(data), exc)
            return False
        if len(port.pending) + len(frame) > MAX_PENDING_OUTPUT:
            self.stats.drops += 1
            return False
        self.stats.messages_out += 1
        port.pending += frame
        if not port.writer_armed:
            self._flush(port)
        return True

    def _flush(self, port):
        while port.pending:
            try:
                written = os.write(port.fd, port.pending)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:
                log.warning("%s: writing %s failed: %s; closing it", self.name, port.name, exc)
                self._close_port(port)
                return
            self.stats.bytes_out += written
            del port.pending[:written]
        if port.pending and not port.writer_armed:
            self._loop.add_writer(port.fd, self._flush, port)
            port.writer_armed = True
        elif not port.pending and port.writer_armed:
            self._loop.remove_writer(port.fd)
            port.writer_armed = False

    def _close_port(self, port):
        if not port.open:
            return
        port.open = False
        loop = self._loop
        loop.remove_reader(port.fd)
        if port.writer_armed:
            loop.remove_writer(port.fd)
            port.writer_armed = False
        if port.pending:  # replies that never reached the wire
            self.stats.drops += 1
            port.pending.clear()
        try:
            port.closer()
        except OSError as exc:
            log.debug("%s: closing %s: %s", self.name, port.name, exc)
        for remote in sorted(port.remotes):
            self._endpoint_closed((port.name, remote))

    async def close(self):
        for port in list(self.ports.values()):
            if port.open and port.pending:
                # Best effort: let the last replies (e.g. DELETE statuses) reach the wire.
                self._flush(port)
            self._close_port(port)


class SerialServer(SerialFramedLink):
    """One or several serial devices opened with pyserial (raw, 8N1, no flow control).

    A device may be a glob (``/dev/serial/by-id/*OpenCR*``): the first match, in sorted order, is
    opened. Hot-plug: when a device fails (EIO or end of file after a USB unplug) its sessions are
    forgotten (``endpoint_closed``) and the same path or glob is tried again every
    ``reopen_interval`` seconds until it opens; the port keeps its name (the path or glob as given),
    so endpoints stay the same across a re-plug. A device that is not there yet at start (no such
    path, no glob match: the board is not plugged in) is waited for the same way, as eProsima's
    agent does, with one line saying so; a device that is there but cannot be opened (permissions,
    not a serial port) is an error at start.
    """

    def __init__(self, receiver, devices, *, baudrate=DEFAULT_BAUDRATE, crc="arc",
                 reopen_interval=DEFAULT_REOPEN_INTERVAL):
        super().__init__(receiver, crc=crc)
        if isinstance(devices, str):
            devices = [devices]
        self.devices = list(devices)
        self.name = "serial" if len(self.devices) == 1 else "multiserial"
        self.baudrate = baudrate
        self.reopen_interval = reopen_interval
        self.reopens = 0
        self._serials = {}
        self._reopen_tasks = {}
        self._closing = False

    async def start(self):
        for device in self.devices:
            if _absent(device):
                log.warning("%s: %s is not there yet; waiting for it (checked every %.1f s)",
                            self.name, device, self.reopen_interval)
                self._reopen_tasks[device] = asyncio.ensure_future(
                    self._reopen(device, reported=True, verb="appeared"))
                continue
            try:
                self._open(device)
            except OSError:
                await self.close()
                raise

    def _open(self, device):
        import serial  # pyserial: termios setup of baud rate and raw mode, portable and well kept

        path = _resolve_device(device)
        try:
            port = serial.Serial(path, self.baudrate, timeout=0, write_timeout=0, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise OSError("cannot open %s: %s" % (device, exc)) from exc
        self._serials[device] = port
        self._add_port(device, port.fileno(), port.close)
        return path

    def _close_port(self, port):
        was_open = port.open
        super()._close_port(port)
        self._serials.pop(port.name, None)
        if was_open and not self._closing and port.name not in self._reopen_tasks:
            log.warning("%s: %s went away; trying to reopen it every %.1f s", self.name, port.name,
                        self.reopen_interval)
            self._reopen_tasks[port.name] = asyncio.ensure_future(self._reopen(port.name))

    async def _reopen(self, device, reported=False, verb="is back"):
        try:
            while not self._closing:
                await asyncio.sleep(self.reopen_interval)
                try:
                    path = self._open(device)
                except OSError as exc:
                    if not reported:
                        reported = True
                        log.info("%s: %s not back yet (%s)", self.name, device, exc)
                    continue
                if verb == "is back":
                    self.reopens += 1
                log.warning("%s: %s %s (%s), serving it", self.name, device, verb, path)
                return
        finally:
            self._reopen_tasks.pop(device, None)

    def describe(self):
        return "%s agent on %s at %d baud" % (self.name, " ".join(self.devices), self.baudrate)

    async def close(self):
        self._closing = True
        for task in list(self._reopen_tasks.values()):
            task.cancel()
        self._reopen_tasks.clear()
        await super().close()


def _absent(device):
    """True when nothing is at ``device`` yet (a board not plugged in), as opposed to something
    there that cannot be opened."""
    if glob.has_magic(device):
        return not glob.glob(device)
    return not os.path.lexists(device) or not os.path.exists(device)


def _resolve_device(device):
    """``device`` itself, or the first (sorted) match when it is a glob pattern."""
    if not glob.has_magic(device):
        return device
    matches = sorted(glob.glob(device))
    if not matches:
        raise OSError("no device matches %s" % device)
    return matches[0]


class PseudoterminalServer(SerialFramedLink):
    """A fresh pty pair: the agent serves the master side, clients open ``slave_path``.

    With ``symlink`` the path is made a symbolic link to the slave (replacing an older link, never a
    regular file) and removed again on close.
    """

    name = "pseudoterminal"

    def __init__(self, receiver, *, symlink=None, crc="arc"):
        super().__init__(receiver, crc=crc)
        self.symlink = symlink
        self.slave_path = None
        self._slave_fd = None
        self._symlink_made = False

    async def start(self):
        master, slave = os.openpty()
        try:
            tty.setraw(slave, termios.TCSANOW)
            self.slave_path = os.ttyname(slave)
            if self.symlink:
                if os.path.islink(self.symlink):
                    os.unlink(self.symlink)
                os.symlink(self.slave_path, self.symlink)
                self._symlink_made = True
        except BaseException:
            os.close(master)
            os.close(slave)
            raise
        # Holding the slave open keeps the master readable (no endless EIO) while no client has it.
        self._slave_fd = slave
        self._add_port(self.slave_path, master, lambda: os.close(master))

    def describe(self):
        text = "pseudoterminal at %s" % self.slave_path
        if self._symlink_made:
            text += " (linked from %s)" % self.symlink
        return text

    async def close(self):
        await super().close()
        if self._slave_fd is not None:
            os.close(self._slave_fd)
            self._slave_fd = None
        if self._symlink_made:
            self._symlink_made = False
            try:
                if os.readlink(self.symlink) == self.slave_path:
                    os.unlink(self.symlink)
            except OSError:
                pass



__all__ = ["SerialFramedLink", "SerialServer", "PseudoterminalServer", "DEFAULT_BAUDRATE"]
