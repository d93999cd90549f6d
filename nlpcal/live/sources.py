"""Where a live stream's lines come from: standard input, a serial port, UDP datagrams.

Every source is read through one descriptor with `select`, so the loop of `nlpcal.live.run`
waits for lines and for its next update at once: `read(timeout)` returns the complete lines
that arrived (an empty list when none did within `timeout` seconds) and None when the stream
ended (standard input at its end; a serial port or a UDP socket does not end by itself).
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import sys

from ..errors import InputError

#: Bytes read at once from a descriptor, and the largest UDP datagram taken.
READ_BYTES = 65536
#: A line longer than this is no sample: it is dropped rather than held.
MAX_LINE = 4096


class LineSource:
    """Lines from a readable descriptor. name : for messages."""

    def __init__(self, name: str, fd: int, datagrams: bool = False):
        self.name = name
        self.fd = fd
        self.datagrams = datagrams
        self._partial = b""
        self.ended = False

    def fileno(self) -> int:
        return self.fd

    def _receive(self) -> bytes | None:
        """The bytes available now: b"" at the end of the stream, None when none came after
        all."""
        return os.read(self.fd, READ_BYTES)

    def read(self, timeout: float) -> list | None:
        """The complete lines that arrived within `timeout` seconds, or None at the end."""
        if self.ended:
            return None
        ready, _, _ = select.select([self.fd], [], [], max(0.0, timeout))
        if not ready:
            return []
        data = self._receive()
        if data is None:
            return []
        if not data and not self.datagrams:
            self.ended = True
            tail, self._partial = self._partial, b""
            return [tail.decode("utf-8", "replace")] if tail.strip() else None
        if self.datagrams:  # a datagram holds whole lines; its last needs no newline
            data += b"\n"
        *lines, self._partial = (self._partial + data).split(b"\n")
        if len(self._partial) > MAX_LINE:
            self._partial = b""
        return [line.decode("utf-8", "replace").rstrip("\r") for line in lines]

    def close(self) -> None:
        """Nothing to close for a descriptor the process was given."""


class StdinSource(LineSource):
    """Standard input (a pipe, a file, a terminal)."""

    def __init__(self):
        super().__init__("stdin", sys.stdin.fileno())


class SerialSource(LineSource):
    """A serial port opened with pyserial (`pip install 'nlpcal[live]'`) at `baud` bit/s."""

    def __init__(self, port: str, baud: int):
        try:
            import serial
        except ImportError:
            raise InputError(
                "--serial needs pyserial: pip install 'nlpcal[live]' (or pip install pyserial)"
            ) from None
        self._serial = serial
        try:
            self.port = serial.Serial(port, baud, timeout=0)
        except (serial.SerialException, ValueError, OSError) as error:
            raise InputError(f"--serial {port}: cannot open the port ({error})") from None
        super().__init__(port, self.port.fileno())

    def _receive(self) -> bytes | None:
        try:
            return bytes(self.port.read(max(1, self.port.in_waiting))) or None
        except self._serial.SerialException:  # the device went away: the end of the stream
            return b""

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.port.close()


class UdpSource(LineSource):
    """UDP datagrams sent to HOST:PORT (one or more lines each)."""

    def __init__(self, address: str):
        host, port = parse_address(address)
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.socket.bind((host, port))
        except OSError as error:
            self.socket.close()
            raise InputError(f"--udp {address}: cannot listen there ({error.strerror})") from None
        super().__init__(f"udp://{host}:{self.socket.getsockname()[1]}", self.socket.fileno(), True)

    def _receive(self) -> bytes | None:
        return self.socket.recv(READ_BYTES)

    def close(self) -> None:
        self.socket.close()


def parse_address(address: str) -> tuple:
    """(host, port) of HOST:PORT (port 0: any free one)."""
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise InputError(
            f"--udp expects HOST:PORT, e.g. 127.0.0.1:5005 or 0.0.0.0:5005; got {address!r}"
        )
    return host or "0.0.0.0", int(port)
