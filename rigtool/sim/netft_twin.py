"""A Net F/T box on loopback: RDT over UDP fed by a LiveTwin, and its netftapi2.xml over HTTP.

The real driver (`rigtool.devices.netft.NetFTSensor`) talks to it unchanged. It honours
start (0x0002, with a sample count), stop (0x0000) and bias (0x0042) requests, numbers
its records like the box (rdt_sequence from 1 per stream, ft_sequence running), and
sends one 36-byte record per LiveTwin sample, so its RDT rate is the LiveTwin's rate.

`faults` switches transport and device misbehaviour on and off while it runs: lost,
reordered, duplicated, malformed and corrupt datagrams, a non-zero status word, and silence.
All of its randomness comes from one seeded generator.
"""

from __future__ import annotations

import contextlib
import queue
import random
import socket
import threading
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, HTTPServer

import numpy as np

from rigtool.devices.netft import (
    CMD_BIAS,
    CMD_START_REALTIME,
    CMD_STOP,
    RDT_HEADER,
    RECORD,
    REQUEST,
)
from rigtool.sim.live import LiveTwin
from rigtool.units import FORCE_UNITS_N, TORQUE_UNITS_NM, unit_factor

_INT32 = (-(1 << 31), (1 << 31) - 1)
_GARBAGE_LENGTHS = [k for k in range(1, 100) if k % RECORD.size]


@dataclass
class NetFTFaults:
    """Misbehaviour switches; fractions are per record, and may be changed while running."""

    drop: float = 0.0  # record never sent (its rdt_sequence is skipped: a lost packet)
    reorder: float = 0.0  # record held back and sent after the next one
    duplicate: float = 0.0  # record sent twice in a row (the network delivered it twice)
    garbage: float = 0.0  # an extra datagram of random bytes (never a multiple of 36 long)
    short: float = 0.0  # record truncated to 1..35 bytes
    oversized: float = 0.0  # record sent with 1..35 extra bytes
    bad_header: float = 0.0  # record sent with random rdt/ft sequence numbers
    status: int = 0  # status word of every record (0 = healthy)
    silent: bool = False  # send nothing at all (requests are still taken)


@dataclass
class NetFTTwinStats:
    requests: int = 0
    bad_requests: int = 0  # wrong size, wrong header or unknown command
    starts: int = 0
    stops: int = 0
    biases: int = 0
    records: int = 0  # records generated while streaming (including dropped ones)
    datagrams: int = 0  # datagrams actually sent


class NetFTTwin:
    """Serves RDT on `host:port` (port 0 = any free one) and netftapi2.xml on `http_port`."""

    def __init__(self, live: LiveTwin, host: str = "127.0.0.1", port: int = 0, *,
                 http_port: int | None = 0, counts_per_force: float = 1_000_000.0,
                 counts_per_torque: float = 1_000_000.0, force_unit: str = "N",
                 torque_unit: str = "N-m", faults: NetFTFaults | None = None, seed: int = 0) -> None:
        self.live = live
        self.faults = faults or NetFTFaults()
        self.stats = NetFTTwinStats()
        self.counts_per_force = counts_per_force
        self.counts_per_torque = counts_per_torque
        self.force_unit, self.torque_unit = force_unit, torque_unit
        # counts per N and per N m, per channel
        self._counts = np.array(
            [counts_per_force / unit_factor(force_unit, FORCE_UNITS_N, "force")] * 3
            + [counts_per_torque / unit_factor(torque_unit, TORQUE_UNITS_NM, "torque")] * 3)
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self._client: tuple | None = None
        self._remaining: int | None = None  # records left in a finite request
        self._rdt_seq = 0
        self._ft_seq = 0
        self._bias = np.zeros(6, dtype=np.int64)
        self._last_counts = np.zeros(6, dtype=np.int64)
        self._held: bytes | None = None
        self._stop = threading.Event()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind((host, port))
        self._sock.settimeout(0.1)
        self._http: HTTPServer | None = None
        if http_port is not None:
            self._http = HTTPServer((host, http_port), self._http_handler())
        self._threads: list[threading.Thread] = []

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the RDT socket listens on."""
        return self._sock.getsockname()[:2]

    @property
    def http_port(self) -> int | None:
        return self._http.server_address[1] if self._http else None

    def start(self) -> NetFTTwin:
        queue_ = self.live.subscribe()
        targets = [self._request_loop, lambda: self._stream_loop(queue_)]
        if self._http is not None:
            targets.append(self._http.serve_forever)
        for target in targets:
            th = threading.Thread(target=target, name="rigtool-netft-twin", daemon=True)
            th.start()
            self._threads.append(th)
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._http is not None:
            if self._threads:
                self._http.shutdown()
            self._http.server_close()
        for th in self._threads:
            th.join(timeout=2.0)
        self._sock.close()

    def __enter__(self) -> NetFTTwin:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def streaming(self) -> bool:
        return self._client is not None

    def netftapi2_xml(self) -> str:
        """The calibration page a real box serves (the elements the driver reads, and a few more)."""
        fields = {
            "prodname": "rigtool Net F/T twin", "setserial": "FT-TWIN", "cfgnam": "twin",
            "cfgcpf": f"{self.counts_per_force:g}", "cfgcpt": f"{self.counts_per_torque:g}",
            "scfgfu": self.force_unit, "scfgtu": self.torque_unit,
            "comrdtrate": f"{self.live.rate_hz:g}", "runstat": f"0x{self.faults.status:08x}",
        }
        body = "".join(f"<{k}>{v}</{k}>" for k, v in fields.items())
        return f'<?xml version="1.0" encoding="utf-8"?>\n<netft>{body}</netft>\n'

    # -- threads --------------------------------------------------------------------------
    def _http_handler(self) -> type[BaseHTTPRequestHandler]:
        twin = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 (http.server's name)
                if self.path.split("?")[0] != "/netftapi2.xml":
                    self.send_error(404)
                    return
                body = twin.netftapi2_xml().encode()
                self.send_response(200)
                self.send_header("Content-Type", "text/xml")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: object) -> None:
                return None

        return Handler

    def _request_loop(self) -> None:
        while not self._stop.is_set():
            try:
                data, addr = self._sock.recvfrom(1024)
            except TimeoutError:
                continue
            except OSError:
                return
            self.stats.requests += 1
            if len(data) != REQUEST.size:
                self.stats.bad_requests += 1
                continue
            header, command, count = REQUEST.unpack(data)
            with self._lock:
                if header != RDT_HEADER:
                    self.stats.bad_requests += 1
                elif command == CMD_START_REALTIME:
                    self.stats.starts += 1
                    self._client, self._remaining = addr, (count or None)
                    self._rdt_seq, self._held = 0, None
                elif command == CMD_STOP:
                    self.stats.stops += 1
                    self._client = None
                elif command == CMD_BIAS:
                    self.stats.biases += 1
                    self._bias = self._bias + self._last_counts
                else:
                    self.stats.bad_requests += 1

    def _stream_loop(self, blocks: queue.Queue) -> None:
        while not self._stop.is_set():
            try:
                block = blocks.get(timeout=0.1)
            except queue.Empty:
                continue
            raw = np.rint(block.ft * self._counts).astype(np.int64)
            with self._lock:
                counts = np.clip(raw - self._bias, *_INT32)
                self._last_counts = counts[-1].copy()
                if self._client is None:
                    continue
                for row in counts:
                    if self._remaining is not None:
                        if self._remaining <= 0:
                            self._client = None
                            break
                        self._remaining -= 1
                    self._emit(row)

    def _emit(self, counts: np.ndarray) -> None:
        """Number one record and send it, with whatever faults are switched on."""
        f, rng = self.faults, self._rng
        self._rdt_seq = (self._rdt_seq + 1) & 0xFFFFFFFF
        self._ft_seq = (self._ft_seq + 1) & 0xFFFFFFFF
        self.stats.records += 1
        if f.silent or (f.drop and rng.random() < f.drop):
            return
        seqs = (self._rdt_seq, self._ft_seq)
        if f.bad_header and rng.random() < f.bad_header:
            seqs = (rng.getrandbits(32), rng.getrandbits(32))
        payload = RECORD.pack(*seqs, f.status, *(int(c) for c in counts))
        if f.short and rng.random() < f.short:
            payload = payload[: rng.randrange(1, RECORD.size)]
        elif f.oversized and rng.random() < f.oversized:
            payload += bytes(rng.randrange(1, RECORD.size))
        if f.reorder and self._held is None and rng.random() < f.reorder:
            self._held = payload
            return
        self._send(payload)
        if f.duplicate and rng.random() < f.duplicate:
            self._send(payload)
        if self._held is not None:
            self._send(self._held)
            self._held = None
        if f.garbage and rng.random() < f.garbage:
            self._send(rng.randbytes(rng.choice(_GARBAGE_LENGTHS)))

    def _send(self, payload: bytes) -> None:
        with contextlib.suppress(OSError):  # the client went away; a real box keeps sending too
            self._sock.sendto(payload, self._client)
            self.stats.datagrams += 1
