"""ATI Net F/T six-axis force/torque sensor over RDT (UDP), calibration from its web page.

Protocol facts (ATI Net F/T manual, "Raw Data Transfer"):

* The host sends 8-byte requests to UDP port 49152: big-endian `>HHI` =
  header 0x1234, command, sample count (0 = until stopped). Commands used here:
  0x0000 stop streaming, 0x0002 start high-speed real-time streaming, 0x0042 set
  software bias (the box zeroes itself on its current reading).
* The box answers from that port with 36-byte records, big-endian `>III6i` =
  rdt_sequence, ft_sequence, status (0 = healthy), then Fx, Fy, Fz, Tx, Ty, Tz in
  counts. A datagram may carry several records (buffered mode); each is used.
* Counts per force unit and per torque unit, and the units themselves, are the
  `cfgcpf`, `cfgcpt`, `scfgfu`, `scfgtu` elements of `http://HOST/netftapi2.xml`;
  `comrdtrate` is the RDT output rate in Hz.

How the box numbers records (ATI Net F/T manual, document 9620-05-NET FT, RDT section,
record fields; ATI's Java demo, com.atiia.automation.sensors.NetFTRDTPacket, whose record
"RDT sequence number increases by one for each packet that is sent"):

* rdt_sequence is "the position of the RDT record within a single output stream": it
  numbers records, not datagrams. It is 1 for the first record after a start request and
  goes up by 1 with each record sent (a request for 1000 records runs from 1 to 1000), and
  wraps to 0 after 2^32 - 1. A buffered-mode datagram carries "RDT output buffer size"
  records, so it holds consecutive numbers and the next datagram goes on from its last
  one. Records are missing exactly where this per-record number skips.
* ft_sequence is "the internal sample number of the F/T record": it counts from power-up
  at the box's internal rate and no request resets it, so it steps by more than 1 between
  records whenever the RDT rate is lower; it says nothing about loss and is not checked.

The receive thread judges every record's rdt_sequence against the last one stored
(`RdtSequence`): exactly 1 ahead, it is stored; equal or behind by up to SEQUENCE_WINDOW, it
is a late record (its number was skipped: `out_of_order`) or a duplicate, and is dropped.
Any other jump, near or far, is held, neither stored nor counted, until the records after it
judge it: once CONFIRM_RECORDS records go on from it, the stream really moved there (a gap,
counted lost, or a restart: `resyncs`) and the held records are stored; once as many go on
from the stream instead, it was corrupt: dropped and counted in `bad_sequence`, with no loss
and no genuine record dropped. A record that completes the stream up to a held run (it had
been overtaken) is stored in its place (`reordered`). docs/drivers/netft.md has the table.

The driver streams in a background thread into a buffer stamped with the monotonic
arrival time, converts counts to N and N m, and keeps statistics of lost, late,
malformed and faulted packets (`stats`, `pop_warnings()`).
"""

from __future__ import annotations

import contextlib
import logging
import math
import selectors
import socket
import struct
import threading
import time
import urllib.error
import urllib.request
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import ClassVar, Literal

import numpy as np
from pydantic import ConfigDict, Field, field_validator, model_validator

from rigtool.bounds import (
    MAX_BUFFER_SAMPLES,
    MAX_RATE_HZ,
    MIN_RATE_HZ,
    PositiveScale,
    PositiveSeconds,
)
from rigtool.devices import mmsg
from rigtool.devices.base import Device, ForceBlock
from rigtool.devices.buffer import SampleBuffer
from rigtool.devices.capabilities import SensorSection
from rigtool.errors import DeviceError
from rigtool.units import FORCE_UNITS_N, FT_CHANNELS, TORQUE_UNITS_NM, unit_factor

log = logging.getLogger(__name__)

RDT_PORT = 49152
RDT_HEADER = 0x1234
CMD_STOP = 0x0000
CMD_START_REALTIME = 0x0002
CMD_BIAS = 0x0042
REQUEST = struct.Struct(">HHI")  # header, command, sample count
RECORD = struct.Struct(">III6i")  # rdt_sequence, ft_sequence, status, Fx..Tz (counts)
RECORD_DTYPE = np.dtype([("seq", ">u4"), ("ft_seq", ">u4"), ("status", ">u4"), ("counts", ">i4", (6,))])
SEQUENCE_WINDOW = 1024  # late records are recognised this far behind the stream
CONFIRM_RECORDS = 2  # a jump is stored once this many records go on from it
RUN_STEP_MAX = 4  # a held run goes on only with a number at most this far past its last
MAX_CANDIDATES = 4  # candidate runs held at once (more: the oldest was corrupt)
MAX_SEQUENCE_JUMP = 1_000_000  # a confirmed move ahead up to this is a gap (lost); more, a restart
_SEQ_MOD = 1 << 32
_BIAS_GUARD_S = 0.02  # after a device bias, records arriving this soon may predate it
# With the kernel's arrival stamp on every datagram (Linux SO_TIMESTAMPNS), the receiver
# wakes every RECEIVE_BATCH_S and takes what queued, instead of once per datagram (7000 a
# second at full rate); each record keeps its own arrival time. Where recvmmsg is available
# (mmsg.py) one system call takes up to RECEIVE_SLOTS datagrams.
RECEIVE_BATCH_S = 0.02
RECEIVE_SLOTS = 512  # 20 ms at 25 kHz
_SO_TIMESTAMPNS = mmsg.SO_TIMESTAMPNS
_TIMESPEC = struct.Struct("@qq")  # the stamp: seconds and nanoseconds since the epoch
_STAMP_SPACE = socket.CMSG_SPACE(_TIMESPEC.size) if hasattr(socket, "CMSG_SPACE") else 64
MAX_DATAGRAM = 4096  # RDT sends 36-byte records; longer datagrams are counted as bad size
_MSG_TRUNC = int(getattr(socket, "MSG_TRUNC", 0))  # a plain int: enum `&` costs 8 us a datagram
_EMPTY, _FAILED = object(), object()  # what `_guarded` returns instead of datagrams

def pack_request(command: int, sample_count: int = 0) -> bytes:
    return REQUEST.pack(RDT_HEADER, command, sample_count)


class NetFTConfig(SensorSection):
    """The `sensor:` section of a rig file for an ATI Net F/T (six axes)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    axes: ClassVar[int] = 6
    measures_torque: ClassVar[bool] = True
    driver: Literal["ati-netft"]
    host: str = Field(min_length=1)
    port: int = Field(RDT_PORT, ge=1, le=65535)
    http_port: int = Field(80, ge=1, le=65535)
    # Calibration: both counts, or neither (then fetched from http://host:http_port/netftapi2.xml).
    counts_per_force: PositiveScale | None = None
    counts_per_torque: PositiveScale | None = None
    force_unit: str = "N"  # unit the configured counts refer to (the box's scfgfu)
    torque_unit: str = "N-m"  # (the box's scfgtu)
    sample_count: int = Field(0, ge=0, lt=_SEQ_MOD)  # per start request; 0 = stream until stopped
    timeout_s: PositiveSeconds = 1.0
    bias: Literal["host", "device"] = "host"
    on_status: Literal["fault", "warn"] = "fault"
    max_gap_s: PositiveSeconds = 0.25
    buffer_samples: int = Field(200_000, ge=1000, le=MAX_BUFFER_SAMPLES)

    @field_validator("force_unit")
    @classmethod
    def _force_unit(cls, v: str) -> str:
        unit_factor(v, FORCE_UNITS_N, "force")
        return v

    @field_validator("torque_unit")
    @classmethod
    def _torque_unit(cls, v: str) -> str:
        unit_factor(v, TORQUE_UNITS_NM, "torque")
        return v

    @model_validator(mode="after")
    def _both_counts(self) -> NetFTConfig:
        if (self.counts_per_force is None) != (self.counts_per_torque is None):
            raise ValueError("give both counts_per_force and counts_per_torque, or neither "
                             "(then they are read from the box's netftapi2.xml)")
        return self

    def stated_rate(self) -> str | None:
        """Without configured counts the box states its RDT rate in netftapi2.xml."""
        return "the box's RDT rate (netftapi2.xml)" if self.counts_per_force is None else None


@dataclass(frozen=True)
class NetFTCalibration:
    """Counts per N and per N m, and where they came from."""

    counts_per_n: float
    counts_per_nm: float
    source: str  # "config" or the URL read
    rate_hz: float | None = None  # the box's RDT output rate, when known
    force_unit: str = "N"
    torque_unit: str = "N-m"


def parse_netftapi2(xml_text: str | bytes, source: str = "netftapi2.xml") -> NetFTCalibration:
    """Calibration from the text of the box's netftapi2.xml (cfgcpf/cfgcpt in scfgfu/scfgtu)."""
    try:
        root = ET.fromstring(xml_text)
    except ET.ParseError as exc:
        raise DeviceError(f"{source}: not valid XML ({exc})") from None
    values = {el.tag.rsplit("}", 1)[-1].lower(): (el.text or "").strip() for el in root.iter()}
    missing = [k for k in ("cfgcpf", "cfgcpt", "scfgfu", "scfgtu") if not values.get(k)]
    if missing:
        raise DeviceError(f"{source}: no {', '.join(missing)} element; give counts_per_force, "
                          "counts_per_torque, force_unit and torque_unit in the rig file")
    try:
        cpf, cpt = float(values["cfgcpf"]), float(values["cfgcpt"])
        fu = unit_factor(values["scfgfu"], FORCE_UNITS_N, "force")
        tu = unit_factor(values["scfgtu"], TORQUE_UNITS_NM, "torque")
    except ValueError as exc:
        raise DeviceError(f"{source}: {exc}") from None
    if cpf <= 0 or cpt <= 0:
        raise DeviceError(f"{source}: counts per force/torque must be positive (got {cpf}, {cpt})")
    try:
        rate = float(values["comrdtrate"]) if values.get("comrdtrate") else None
    except ValueError:
        rate = None  # unreadable: the rate is measured
    if rate is not None and not (math.isfinite(rate) and MIN_RATE_HZ <= rate <= MAX_RATE_HZ):
        raise DeviceError(f"{source}: comrdtrate {values['comrdtrate']!r} is not a usable RDT "
                          f"rate (finite, {MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} Hz)")
    return NetFTCalibration(cpf / fu, cpt / tu, source, rate, values["scfgfu"], values["scfgtu"])


def fetch_calibration(host: str, http_port: int = 80, timeout_s: float = 1.0) -> NetFTCalibration:
    """Read counts per force/torque from http://host:http_port/netftapi2.xml."""
    url = f"http://{host}:{http_port}/netftapi2.xml"
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as response:
            text = response.read()
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise DeviceError(f"cannot read the Net F/T calibration from {url}: {reason}; check host "
                          "and http_port, or give counts_per_force and counts_per_torque") from None
    return parse_netftapi2(text, url)


@dataclass
class NetFTStats:
    """What the receive thread has seen since the driver opened."""

    datagrams: int = 0  # every datagram from the box
    records: int = 0  # records accepted into the buffer
    lost_packets: int = 0  # rdt_sequence numbers (records) missing from the accepted stream
    out_of_order: int = 0  # late records: behind the stream, in a gap counted lost (discarded)
    duplicates: int = 0  # records whose rdt_sequence was already received (discarded)
    reordered: int = 0  # records overtaken while the jump after them was held (kept in place)
    bad_size: int = 0  # datagrams whose length is not a multiple of 36 bytes
    bad_sequence: int = 0  # far records the next did not confirm (corrupt), or left at a restart
    resyncs: int = 0  # far moves of the stream that the next record confirmed (followed)
    status_records: int = 0  # records with a non-zero status word
    last_status: int = 0
    starts: int = 0  # start requests sent (first one, re-arms, restarts)
    restarts: int = 0  # starts sent because the stream went quiet
    refused: int = 0  # ICMP "port unreachable" replies: nothing listening at host:port
    stale: int = 0  # samples dropped because they arrived in a pause between reads (max_gap_s)
    overflowed: int = 0  # buffered samples dropped because the buffer was full


def _monotone(items: list[tuple]) -> list[tuple]:
    """`items` in sequence order with arrival times made non-decreasing: a late record that
    completes a held run takes the time of the first record after it."""
    out, t = [], math.inf
    for item in reversed(items):
        t = min(t, item[0])
        out.append(item if item[0] == t else (t, *item[1:]))
    return out[::-1]


class RdtSequence:
    """The rdt_sequence of one output stream, judged record by record (see the module
    docstring); `offer` and `take_run` say what to store, and counts go into `stats`."""

    def __init__(self, stats: NetFTStats) -> None:
        self.stats = stats
        self.last: int | None = None  # rdt_sequence of the last record stored
        self._held: list[list[tuple]] = []  # candidate runs after a jump, until judged
        self._passed: list[int] = []  # records stored since each candidate came
        self._missing: set[int] = set()  # numbers skipped, within SEQUENCE_WINDOW of `last`

    def restart(self) -> None:
        """A start request went out: the box numbers the new stream from 1."""
        self._drop_all()
        self.last = None
        self._missing.clear()

    def offer(self, item: tuple) -> list[tuple]:
        """The records to store now, in order, given the next one (t, seq, status, counts...)."""
        seq, base = item[1], self._base()
        ahead = (seq - base) % _SEQ_MOD
        if ahead == 1:
            return self._store_next(item)
        if self.last is not None and (not ahead or _SEQ_MOD - ahead <= SEQUENCE_WINDOW):
            self._behind(seq)
            return []
        for k, run in enumerate(self._held):
            step = (seq - run[-1][1]) % _SEQ_MOD
            if not step:
                self.stats.duplicates += 1
                return []
            if step <= RUN_STEP_MAX:  # a near number joins a run; farther starts another
                run.append(item)
                return self._confirm(k) if len(run) > CONFIRM_RECORDS else []
        self._held.append([item])
        self._passed.append(0)
        if len(self._held) > MAX_CANDIDATES:
            self._drop(0)
        return []

    def take_run(self, seq: np.ndarray) -> bool:
        """Take uint32 `seq` at once if each is 1 ahead of the one before and none is held."""
        if self._held or not len(seq):
            return False
        ahead = np.empty(len(seq), np.uint32)  # steps modulo 2^32, as uint32 arithmetic wraps
        ahead[0] = (int(seq[0]) - self._base()) % _SEQ_MOD
        np.subtract(seq[1:], seq[:-1], out=ahead[1:])
        if (ahead != 1).any():
            return False
        self.last = int(seq[-1])
        return True

    def take_consecutive(self, seqs: list[int]) -> bool:
        """Take a datagram's records at once if they number on from the stream one by one."""
        first = seqs[0]
        if self._held or first != (self._base() + 1) % _SEQ_MOD or seqs != list(
                range(first, first + len(seqs))):
            return False  # the wrap past 2^32 is left to `offer`
        self.last = seqs[-1]
        return True

    def _base(self) -> int:
        """The number the next record should follow: the last stored, 0 before a stream."""
        return 0 if self.last is None else self.last

    def _store_next(self, item: tuple) -> list[tuple]:
        """Store the record that goes on from the stream, then any candidate run it reaches;
        a candidate passed by CONFIRM_RECORDS stored records was corrupt."""
        self.last = item[1]
        out = [item]
        self._passed = [p + 1 for p in self._passed]
        released = True
        while released:
            released = False
            for k, run in enumerate(self._held):
                if run[0][1] == (self.last + 1) % _SEQ_MOD:
                    self.stats.reordered += 1
                    out += self._take(run)
                    self._held.pop(k)
                    self._passed.pop(k)
                    released = True
                    break
        for k in reversed(range(len(self._held))):
            if self._passed[k] >= CONFIRM_RECORDS:
                self._drop(k)
        return _monotone(out) if len(out) > 1 else out

    def _confirm(self, k: int) -> list[tuple]:
        """Candidate run k went on for CONFIRM_RECORDS records: the stream really moved there
        (a gap, or a restart). On a gap within the window, the candidates that lie between
        the stream and the run, in order, are stored before it (a further gap split them off);
        candidates still ahead within the window stay held; the others were corrupt."""
        run = self._held.pop(k)
        self._passed.pop(k)
        first = run[0][1]
        near = self.last is None or (first - self.last) % _SEQ_MOD <= SEQUENCE_WINDOW
        if near:
            out = self._take_between(first)
        else:
            out = []
            self._drop_all()
        self._follow(first)
        out += [run[0], *self._take(run[1:])]
        for j in reversed(range(len(self._held))):
            if not 0 < (self._held[j][0][1] - self.last) % _SEQ_MOD <= SEQUENCE_WINDOW:
                self._drop(j)
        return _monotone(out) if len(out) > 1 else out

    def _take_between(self, first: int) -> list[tuple]:
        """Store the candidates that lie wholly between the stream (or, at a stream's start,
        SEQUENCE_WINDOW before it) and the confirmed run's `first`, lowest first."""
        base = (first - SEQUENCE_WINDOW - 1) % _SEQ_MOD if self.last is None else self.last
        ahead = (first - base) % _SEQ_MOD
        between = sorted((j for j, run in enumerate(self._held)
                          if 0 < (run[-1][1] - base) % _SEQ_MOD < ahead
                          and (run[0][1] - base) % _SEQ_MOD <= (run[-1][1] - base) % _SEQ_MOD),
                         key=lambda j: (self._held[j][0][1] - base) % _SEQ_MOD)
        out: list[tuple] = []
        for j in between:
            run = self._held[j]
            if self.last is None:  # the stream starts with this candidate
                self._follow(run[0][1])
                out.append(run[0])
                run = run[1:]
            out += self._take(run)
        for j in sorted(between, reverse=True):
            self._held.pop(j)
            self._passed.pop(j)
        return out

    def _take(self, run: list[tuple]) -> list[tuple]:
        """Store a run that goes on from `last`, counting the numbers it skips as lost."""
        for item in run:
            ahead = (item[1] - self._base()) % _SEQ_MOD
            if ahead > 1:
                self._skip(self._base(), ahead)
            self.last = item[1]
        return list(run)

    def _drop(self, k: int) -> None:
        """Candidate run k was never confirmed: its records were corrupt."""
        self.stats.bad_sequence += len(self._held.pop(k))
        self._passed.pop(k)

    def _drop_all(self) -> None:
        while self._held:
            self._drop(0)

    def _follow(self, seq: int) -> None:
        """The stream really moved to `seq`: a gap (lost) or a restart."""
        last, self.last = self.last, seq
        if last is None:  # the box numbers a stream from 1; farther, it joined a running one
            if seq <= SEQUENCE_WINDOW:
                self._skip(0, seq)
            return
        ahead = (seq - last) % _SEQ_MOD
        if ahead <= SEQUENCE_WINDOW:
            self._skip(last, ahead)
            return
        self.stats.resyncs += 1
        if ahead <= MAX_SEQUENCE_JUMP:
            self._skip(last, ahead)
        else:
            self._missing.clear()

    def _skip(self, last: int, ahead: int) -> None:
        """Count the ahead - 1 numbers after `last` lost, remembering the latest of them."""
        self.stats.lost_packets += ahead - 1
        missing = self._missing
        missing.update((last + k) % _SEQ_MOD for k in range(max(1, ahead - SEQUENCE_WINDOW), ahead))
        if len(missing) > 2 * SEQUENCE_WINDOW:
            top = (last + ahead) % _SEQ_MOD
            self._missing = {m for m in missing if (top - m) % _SEQ_MOD <= SEQUENCE_WINDOW}

    def _behind(self, seq: int) -> None:
        """A record at or behind the stream: late if its number was skipped, else a duplicate."""
        if seq in self._missing:
            self._missing.discard(seq)
            self.stats.out_of_order += 1
        else:
            self.stats.duplicates += 1


class NetFTSensor(Device):
    """ForceSensor for an ATI Net F/T box (or NetFTTwin) at `config.host:config.port`.

    `read(n, rate_hz)` returns the next `n` records at the box's own RDT rate: `rate_hz`
    is advisory. `set_bias` adds to a host-side bias (or, with `bias: device`, sends the
    box's own bias command). Non-zero status words fail the read (`on_status: fault`) or
    are recorded as warnings (`on_status: warn`).
    """

    channels = FT_CHANNELS
    stats_gauges = ("last_status", "buffered")  # states in `stats`, not counters

    def __init__(self, config: NetFTConfig | Mapping, *, now: Callable[[], float] = time.monotonic
                 ) -> None:
        cfg = config if isinstance(config, NetFTConfig) else NetFTConfig.model_validate(config)
        self.config = cfg
        self.name = f"Net F/T at {cfg.host}:{cfg.port}"
        self._now = now
        if cfg.counts_per_force is None or cfg.counts_per_torque is None:
            self.calibration = fetch_calibration(cfg.host, cfg.http_port, cfg.timeout_s)
        else:
            self.calibration = NetFTCalibration(
                cfg.counts_per_force / unit_factor(cfg.force_unit, FORCE_UNITS_N, "force"),
                cfg.counts_per_torque / unit_factor(cfg.torque_unit, TORQUE_UNITS_NM, "torque"),
                "config", None, cfg.force_unit, cfg.torque_unit)
        cal = self.calibration
        self._scale = np.array([1.0 / cal.counts_per_n] * 3 + [1.0 / cal.counts_per_nm] * 3)
        self._bias = np.zeros(6)
        self._stats = NetFTStats()
        self._warnings: list[str] = []
        self._lock = threading.Lock()  # sequence state, shared by both threads
        self._seq = RdtSequence(self._stats)
        self._since_start = 0
        self._discard_until = -np.inf
        self._buffer = SampleBuffer(cfg.buffer_samples)
        self._stop = threading.Event()
        self._first = threading.Event()
        self._sock = self._open_socket()
        self._batched = self._kernel_stamps()
        self._batch_s = RECEIVE_BATCH_S
        self._multi = (mmsg.MultiReceiver(self._sock, RECEIVE_SLOTS, MAX_DATAGRAM)
                       if self._batched and mmsg.available() else None)
        self._thread = threading.Thread(target=self._receive_loop, name="rigtool-netft", daemon=True)
        self._thread.start()
        try:
            self._start_streaming()
            if not self._first.wait(cfg.timeout_s):
                raise DeviceError(
                    f"{self.name}: no RDT data within {cfg.timeout_s:g} s of the start request "
                    f"({self._describe_silence()})")
        except BaseException:
            self.close()
            raise

    numbers_samples = True  # `seq` is rdt_sequence: one number per record the box sent

    @property
    def rate_hz(self) -> float | None:
        """The box's RDT rate from its netftapi2.xml (None: not read; the sweep measures it)."""
        return self.calibration.rate_hz

    # -- ForceSensor ----------------------------------------------------------------------
    def read(self, n: int, rate_hz: float) -> ForceBlock:
        """The next `n` records (at the box's rate; `rate_hz` is advisory)."""
        if self._closed:
            raise DeviceError(f"{self.name}: read after close")
        cfg = self.config
        if n <= 0:
            return ForceBlock(np.empty(0), np.empty((0, 6)), np.empty(0, dtype=np.int64))
        self._buffer.begin_read(self._now(), cfg.max_gap_s)
        poll_s = min(0.1, cfg.timeout_s / 4)
        out: list[tuple] = []
        last_progress = self._now()
        restarted = False
        while len(out) < n:
            if cfg.sample_count and self._since_start >= cfg.sample_count:
                self._start_streaming()  # the box has sent the batch it was asked for
            got = self._buffer.take(n - len(out), poll_s)
            if got:
                out.extend(got)
                last_progress, restarted = self._now(), False
                continue
            idle = self._now() - last_progress
            if idle >= cfg.timeout_s:
                raise DeviceError(f"{self.name}: no RDT data for {idle:.1f} s ({len(out)} of {n} "
                                  f"samples read; {self._describe_silence()})")
            if idle >= cfg.timeout_s / 2 and not restarted:
                restarted = True
                self._stats.restarts += 1
                self._warn(f"{self.name}: stream quiet for {idle:.2f} s; sent a new start request")
                self._start_streaming()
        self._buffer.end_read(self._now())
        arr = np.asarray(out, dtype=float)
        status = arr[:, 2]
        bad = np.flatnonzero(status)
        if len(bad) and cfg.on_status == "fault":
            raise DeviceError(
                f"{self.name}: status word 0x{int(status[bad[0]]):08x} on {len(bad)} of {n} samples "
                "(sensor saturated or faulted; see the box's web page). Set `on_status: warn` to "
                "record such samples and carry on")
        ft = arr[:, 3:] * self._scale - self._bias
        return ForceBlock(arr[:, 0], ft, arr[:, 1].astype(np.int64))

    def set_bias(self, bias: np.ndarray) -> None:
        """Subtract `bias` (N, N m) from later samples, on top of earlier biases.

        With `bias: device` the box's own bias command is sent instead: the box zeroes
        itself on its current reading, and the host bias is reset.
        """
        b = np.asarray(bias, dtype=float).reshape(-1)
        if b.shape != (6,) or not np.all(np.isfinite(b)):
            raise ValueError(f"{self.name}: bias must be 6 finite numbers, got {bias!r}")
        if self.config.bias == "device":
            self._send(CMD_BIAS)
            self._bias = np.zeros(6)
            self._discard_until = self._now() + _BIAS_GUARD_S
            self._buffer.clear()
        else:
            self._bias = self._bias + b

    def _release(self) -> None:
        """Stop streaming and release the socket (on `close`)."""
        with contextlib.suppress(OSError, DeviceError):
            self._send(CMD_STOP)
        self._stop.set()
        self._buffer.fail(DeviceError(f"{self.name}: closed"))  # wakes a read in another thread
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
        self._sock.close()

    # -- diagnostics ----------------------------------------------------------------------
    @property
    def stats(self) -> dict:
        """Counters since open (see NetFTStats), plus samples waiting in the buffer."""
        self._stats.stale, self._stats.overflowed = self._buffer.stale, self._buffer.overflowed
        return {**asdict(self._stats), "buffered": len(self._buffer)}

    def pop_warnings(self) -> list[str]:
        """Warnings (status words, restarts) since the previous call, oldest first."""
        with self._lock:
            out, self._warnings = self._warnings, []
        return out

    # -- internals ------------------------------------------------------------------------
    def _open_socket(self) -> socket.socket:
        cfg = self.config
        try:
            family, kind, proto, _, addr = socket.getaddrinfo(
                cfg.host, cfg.port, type=socket.SOCK_DGRAM)[0]
        except socket.gaierror as exc:
            raise DeviceError(f"{self.name}: cannot resolve host {cfg.host!r}: {exc}") from None
        sock = socket.socket(family, kind, proto)
        with contextlib.suppress(OSError):  # room for bursts at 7 kHz; the OS may cap it
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        try:
            sock.connect(addr)  # the kernel then only delivers datagrams from the box
        except OSError as exc:
            sock.close()
            raise DeviceError(f"{self.name}: cannot reach the box: {exc}") from None
        sock.setblocking(False)  # the receive loop waits with a selector and drains
        return sock

    def _send(self, command: int, count: int = 0) -> None:
        try:
            self._sock.send(pack_request(command, count))
        except OSError as exc:
            raise DeviceError(f"{self.name}: cannot send RDT command 0x{command:04x}: {exc}") from None

    def _start_streaming(self) -> None:
        with self._lock:
            self._seq.restart()  # the box numbers a new stream afresh
            self._since_start = 0
            self._stats.starts += 1
        self._send(CMD_START_REALTIME, self.config.sample_count)

    def _describe_silence(self) -> str:
        s = self._stats
        if s.refused:
            return "the host answers that nothing listens on that UDP port"
        if s.datagrams and not s.records:
            return (f"{s.datagrams} datagrams arrived but none was a valid RDT record "
                    f"({s.bad_size} of wrong size, {s.bad_sequence} with a corrupt sequence)")
        return "check the address, that RDT is enabled on the box, and the firewall"

    def _warn(self, message: str) -> None:
        log.warning(message)
        with self._lock:
            self._warnings.append(message)

    def _kernel_stamps(self) -> bool:
        """Ask the kernel to stamp each datagram's arrival; only where the driver runs on
        the monotonic clock the stamps are converted to (not a test's virtual clock)."""
        if self._now is not time.monotonic or _SO_TIMESTAMPNS is None:
            return False
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
        except OSError:
            return False
        return True

    def _receive_loop(self) -> None:
        """Wait for datagrams, take every one queued, check and buffer them. With kernel
        stamps, sleep RECEIVE_BATCH_S between batches; without, wake for each datagram."""
        ready = selectors.DefaultSelector()
        ready.register(self._sock, selectors.EVENT_READ)
        try:
            while not self._stop.is_set():
                if not ready.select(0.1):
                    continue
                if self._multi is not None:
                    if not self._take_many(self._multi):
                        return
                else:
                    batch = self._take_queued()
                    if batch is None:
                        return
                    self._handle(batch)
                if self._batched:
                    time.sleep(self._batch_s)
        finally:
            ready.close()

    def _guarded(self, receive: Callable[[], object]) -> object:
        """receive() with the socket's errors handled: _EMPTY when nothing is queued,
        _FAILED once the socket failed or closed; refusals (ICMP) are counted and retried."""
        while True:
            try:
                return receive()
            except BlockingIOError:
                return _EMPTY
            except ConnectionRefusedError:
                self._stats.refused += 1
            except OSError as exc:
                if not self._stop.is_set():
                    self._buffer.fail(DeviceError(f"{self.name}: receive failed: {exc}"))
                return _FAILED

    def _take_many(self, receiver: mmsg.MultiReceiver) -> bool:
        """Take and handle every queued datagram, up to RECEIVE_SLOTS per system call;
        False once the socket failed or closed."""
        while True:
            wall_minus_mono = time.time() - time.monotonic()
            batch = self._guarded(receiver.receive)
            if batch is _EMPTY or batch is _FAILED:
                return batch is _EMPTY
            t = batch.stamps - wall_minus_mono
            missing = np.isnan(t)
            if missing.any():
                t[missing] = self._now()
                self._batch_s = 0.0  # no kernel stamps after all: time datagrams as they come
            if not self._take_records(batch, t):
                self._handle([(batch.datagram(i), float(t[i])) for i in range(len(batch))])
            if len(batch) < RECEIVE_SLOTS:
                return True

    def _take_records(self, batch: mmsg.Batch, t: np.ndarray) -> bool:
        """Buffer a batch in which every datagram is one healthy record continuing the
        sequence, all at once (the common case); False, having changed nothing, for any
        other batch, which `_handle` then checks datagram by datagram."""
        n = len(batch)
        if (not n or batch.truncated.any() or batch.lengths.min() != RECORD.size
                or batch.lengths.max() != RECORD.size):
            return False
        rec = np.ascontiguousarray(batch.data[:, :RECORD.size]).view(RECORD_DTYPE)[:, 0]
        if rec["status"].any() or t.min() < self._discard_until:
            return False
        seq = rec["seq"].astype(np.uint32)
        with self._lock:
            if not self._seq.take_run(seq):
                return False
            self._since_start += n
        s = self._stats
        s.datagrams += n
        s.records += n
        s.last_status = 0
        self._buffer.put_many(np.column_stack([t, seq, rec["status"], rec["counts"]]).tolist())
        self._first.set()
        return True

    def _take_queued(self) -> list[tuple[bytes, float]] | None:
        """Every queued (datagram, arrival time); None once the socket failed or closed."""
        batch = []
        wall_minus_mono = time.time() - time.monotonic()
        sock = self._sock
        receive = ((lambda: sock.recvmsg(MAX_DATAGRAM, _STAMP_SPACE)) if self._batched
                   else (lambda: (sock.recv(MAX_DATAGRAM + 1), None, 0, None)))
        while True:
            got = self._guarded(receive)
            if got is _EMPTY or got is _FAILED:
                return batch if got is _EMPTY else None
            data, ancillary, flags, _ = got
            if flags & _MSG_TRUNC or len(data) > MAX_DATAGRAM:
                data = b""  # longer than any RDT datagram: a bad size, not a cut record
            t = self._now() if ancillary is None else self._arrival(ancillary, wall_minus_mono)
            batch.append((data, t))

    def _arrival(self, ancillary: list, wall_minus_mono: float) -> float:
        """A datagram's arrival time on the monotonic clock, from its kernel stamp. Without
        one (the option was not honoured) it is now, and batching stops for exact times."""
        for level, kind, data in ancillary:
            if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(data) >= _TIMESPEC.size:
                sec, nsec = _TIMESPEC.unpack_from(data)
                return sec + nsec * 1e-9 - wall_minus_mono
        self._batch_s = 0.0
        return self._now()

    def _handle(self, datagrams: list[tuple[bytes, float]]) -> None:
        """Check (size, sequence, status word) and buffer (datagram, arrival time) pairs,
        with one buffer put and one wake-up of a waiting read for them all."""
        s = self._stats
        items: list[tuple] = []
        for data, t in datagrams:
            s.datagrams += 1
            if not data or len(data) % RECORD.size:
                s.bad_size += 1
                continue
            items += self._judge_records(data, t)
        if items and items[0][0] < self._discard_until:  # in arrival order: the first is oldest
            items = [item for item in items if item[0] >= self._discard_until]  # predate a bias?
        self._note_status(items)
        s.records += len(items)
        if items:
            self._buffer.put_many(items)
            self._first.set()

    def _judge_records(self, data: bytes, t: float) -> list[tuple]:
        """The records of one datagram, and any held before, that the sequence checks store."""
        records = list(RECORD.iter_unpack(data))
        sequence = self._seq
        with self._lock:
            if len(records) > 1 and sequence.take_consecutive([rec[0] for rec in records]):
                kept = [(t, rec[0], rec[2], *rec[3:]) for rec in records]
            else:
                kept = [item for rec in records
                        for item in sequence.offer((t, rec[0], rec[2], *rec[3:]))]
            self._since_start += len(kept)
        return kept

    def _note_status(self, items: list[tuple]) -> None:
        """Count records with a non-zero status word, warning when the word changes."""
        s = self._stats
        if items and not any(item[2] for item in items):
            s.last_status = 0
            return
        for item in items:
            status = item[2]
            if status:
                s.status_records += 1
                if status != s.last_status:
                    self._warn(f"{self.name}: status word 0x{status:08x} (rdt_sequence {item[1]})")
            s.last_status = status
