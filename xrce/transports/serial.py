# Serial client transport: XRCE messages in HDLC-like frames (XRCE-WIRE.md §11).
#
# ``device`` is a port name for pyserial (CPython), a ``machine.UART`` id (MicroPython), or any
# byte-stream object, on either: a configured ``machine.UART``, a USB CDC stream, a port's own UART
# driver. Such an object needs only the three calls the transport makes:
#
# - ``any()``: how many received bytes are waiting (0 when none; the transport polls it);
# - ``readinto(buf, n)``: up to ``n`` of them into ``buf`` (called with ``n <= any()``), their count;
# - ``write(buf, off, n)``: ``buf[off:off + n]`` out, the count written (0 or None when it cannot
#   take more yet: offered again 1 ms later). MicroPython's streams (machine.UART, USB_VCP) take
#   these arguments; the transport never passes a slice, which would be an object per write.
#
# Its ``deinit()`` is called only on a UART the transport made from an id. The client's address
# defaults to 1 and the agent's to 0, as ``uxr_init_serial_transport`` is used by the examples and
# by rmw's serial transport.

from xrce import EncodeError, IS_MICROPYTHON, sleep_ms, ticks_add, ticks_diff, ticks_ms
from xrce.transports import TransportError
from xrce.transports.crc import get_crc
from xrce.transports.framing import FrameDecoder, encode_frame, write_frame

try:
    import serial as _pyserial  # pyserial
except ImportError:  # MicroPython
    _pyserial = None

try:
    import select as _select
except ImportError:  # pragma: no cover
    _select = None

_SerialError = _pyserial.SerialException if _pyserial is not None else OSError

DEFAULT_MTU = 512
# Read size per syscall; frames are at most 2 * (mtu + 6) + 1 bytes escaped, most far smaller.
_CHUNK = 256
# A board writes a frame through a buffer this size, escaping as it goes (see _send_uart).
_OUT_CHUNK = 64


class SerialTransport:
    # Synchronous framed serial link to the agent; the constructor opens the port.
    #
    # Frames sent carry src=``local_addr``, dst=``remote_addr``. Received frames whose dst is not
    # ``local_addr`` (``decoder.wrong_address``) or whose src is not ``remote_addr``
    # (``wrong_source``) are dropped, as the C client does. ``send(msg) -> bool``;
    # ``recv(timeout_ms)`` -> bytes of one message or None after the timeout. Counters: ``sent``,
    # ``received``, ``send_errors``, ``wrong_source`` and the framing counters in ``decoder``.
    #
    # ``recv_frame(timeout_ms)`` -> the length of the message now in ``decoder.buffer`` (valid until
    # the next receive), or -1 after the timeout: the receive a board makes without allocating
    # (UART.readinto into a preallocated chunk, FrameDecoder.scan). On MicroPython ``recv`` is
    # ``recv_frame`` plus the copy it returns, and ``send`` writes the frame through a 64-byte
    # buffer, escaping as it goes, with UART.write(buf, off, n): neither allocates. A stream object
    # given as ``device`` is driven the same way on CPython.

    __slots__ = (
        "device",
        "baudrate",
        "local_addr",
        "remote_addr",
        "mtu",
        "sent",
        "received",
        "send_errors",
        "wrong_source",
        "decoder",
        "_crc",
        "_port",
        "_uart",
        "_pending",
        "_buf",
        "_view",
        "_poller",
        "_out",
        "_flush",
        "_chunk_pos",
        "_chunk_end",
    )

    def __init__(self, device, baudrate=115200, local_addr=1, remote_addr=0, crc="arc", mtu=DEFAULT_MTU):
        self.device = device
        self.baudrate = baudrate
        self.local_addr = local_addr
        self.remote_addr = remote_addr
        self.mtu = mtu
        self._crc = get_crc(crc)
        self.sent = 0
        self.received = 0
        self.send_errors = 0
        self.wrong_source = 0
        self.decoder = FrameDecoder(local_addr=local_addr, max_payload=mtu, crc=self._crc)
        self._port = None  # pyserial
        self._uart = None  # machine.UART
        self._pending = []
        self._buf = bytearray(_CHUNK)
        self._view = memoryview(self._buf)
        self._out = None
        self._flush = self._write_out  # bound once: a bound method per send is an allocation
        self._chunk_pos = self._chunk_end = 0  # what recv_frame has not scanned yet of _buf
        self._poller = None
        self.open()

    def open(self):
        if self._port is not None or self._uart is not None:
            return
        if IS_MICROPYTHON or hasattr(self.device, "readinto"):
            if isinstance(self.device, int):
                import machine

                self._uart = machine.UART(self.device, self.baudrate)
            else:
                self._uart = self.device  # a UART the caller configured (pins, buffers), any stream
            if self._out is None:
                self._out = bytearray(_OUT_CHUNK)
            self.decoder.reset()
            self._chunk_pos = self._chunk_end = 0
            return
        if _pyserial is None:
            raise TransportError("pyserial is required for the serial transport on CPython")
        try:
            # timeout=0: reads return what is buffered; waiting is done with select (below).
            self._port = _pyserial.Serial(self.device, self.baudrate, timeout=0)
        except (OSError, ValueError, _pyserial.SerialException) as error:
            raise TransportError("cannot open serial port %s: %s" % (self.device, error))
        self._poller = None
        if _select is not None and hasattr(_select, "poll"):
            try:
                poller = _select.poll()
                poller.register(self._port.fileno(), _select.POLLIN)
                self._poller = poller
            except (AttributeError, OSError, ValueError):
                self._poller = None  # e.g. Windows: fall back to pyserial's own timeout
        self.decoder.reset()
        self._pending = []
        self._chunk_pos = self._chunk_end = 0

    def close(self):
        if self._port is not None:
            self._port.close()
            self._port = None
        if self._uart is not None:
            if isinstance(self.device, int):
                self._uart.deinit()
            self._uart = None

    def send(self, msg):
        if len(msg) > self.mtu:
            raise EncodeError("message of %d bytes exceeds the serial MTU %d" % (len(msg), self.mtu))
        if self._uart is not None:
            try:
                written = self._send_uart(msg)
            except OSError:
                written = False
            if not written:
                self.send_errors += 1
                return False
            self.sent += 1
            return True
        frame = encode_frame(msg, self.local_addr, self.remote_addr, self._crc)
        try:
            if self._port is not None:
                # pyserial writes straight to the fd on POSIX; no flush() (tcdrain would wait for
                # the bits to leave the UART, which the C client does not do either).
                written = self._port.write(frame)
            else:
                raise TransportError("serial transport is closed")
        except (OSError, _SerialError):
            self.send_errors += 1
            return False
        if written != len(frame):
            self.send_errors += 1
            return False
        self.sent += 1
        return True

    def _send_uart(self, msg):
        return write_frame(self._out, _OUT_CHUNK, msg, self.local_addr, self.remote_addr,
                           self._crc(msg), self._flush)

    def _write_out(self, count):
        uart = self._uart
        position = 0
        while position < count:
            written = uart.write(self._out, position, count - position)
            if written:
                position += written
            else:
                sleep_ms(1)  # TX buffer full
        return True

    def _read_available(self, wait_ms):
        # Up to _CHUNK bytes read into _buf within wait_ms (possibly none): their count.
        if self._uart is not None:
            uart = self._uart
            available = uart.any()
            if not available:
                if wait_ms > 0:
                    sleep_ms(1)
                return 0
            # Never ask for more than is buffered: UART reads may otherwise wait for its timeout.
            count = uart.readinto(self._buf, available if available < _CHUNK else _CHUNK)
            return count or 0
        port = self._port
        if port is None:
            raise TransportError("serial transport is closed")
        if self._poller is not None:
            if not self._poller.poll(wait_ms if wait_ms > 0 else 0):
                return 0
        elif not port.in_waiting:
            port.timeout = wait_ms / 1000 if wait_ms > 0 else 0
            data = port.read(1)
            port.timeout = 0
            if not data:
                return 0
            self._buf[0] = data[0]
            return 1 + port.readinto(self._view[1:])
        return port.readinto(self._buf) or 0

    def recv_frame(self, timeout_ms):
        decoder = self.decoder
        buf = self._buf
        deadline = ticks_add(ticks_ms(), timeout_ms)
        remaining = timeout_ms
        while True:
            pos = self._chunk_pos
            end = self._chunk_end
            while pos < end:
                pos = decoder.scan(buf, pos, end)
                if decoder.frame_length >= 0:
                    if decoder.frame_src == self.remote_addr:
                        self._chunk_pos = pos
                        self.received += 1
                        return decoder.frame_length
                    self.wrong_source += 1
            self._chunk_pos = 0
            self._chunk_end = self._read_available(remaining)
            if not self._chunk_end:
                remaining = ticks_diff(deadline, ticks_ms())
                if remaining <= 0:
                    return -1

    def recv(self, timeout_ms):
        if IS_MICROPYTHON:
            length = self.recv_frame(timeout_ms)
            return None if length < 0 else bytes(memoryview(self.decoder.buffer)[:length])
        return self.decoder.receive(self, timeout_ms)

