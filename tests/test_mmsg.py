"""recvmmsg batches over loopback UDP: lengths, truncation, kernel stamps, errors."""

from __future__ import annotations

import select
import socket
import time

import numpy as np
import pytest

from rigtool.devices import mmsg

pytestmark = pytest.mark.skipif(not mmsg.available(), reason="recvmmsg is Linux, 64-bit")


@pytest.fixture
def pair():
    """(receiver socket with kernel stamps, connected sender socket) on loopback."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    tx.bind(("127.0.0.1", 0))
    rx.connect(tx.getsockname())
    tx.connect(rx.getsockname())
    rx.setblocking(False)
    rx.setsockopt(socket.SOL_SOCKET, mmsg.SO_TIMESTAMPNS, 1)
    yield rx, tx
    rx.close()
    tx.close()


def _wait_queued(rx: socket.socket) -> None:
    """Until the first datagram is queued, and a moment more for the rest (loopback)."""
    select.select([rx], [], [], 2.0)
    time.sleep(0.05)


def test_nothing_queued_is_blocking_io_error(pair):
    rx, _ = pair
    with pytest.raises(BlockingIOError):
        mmsg.MultiReceiver(rx, slots=4, slot_size=64).receive()


def test_one_call_takes_every_queued_datagram_with_its_own_length_and_stamp(pair):
    rx, tx = pair
    sent = [bytes([i]) * (7 * i) for i in range(10)] + [b"x" * 100]  # the last is too long
    t_before = time.time()
    for d in sent:
        tx.send(d)
    _wait_queued(rx)
    batch = mmsg.MultiReceiver(rx, slots=16, slot_size=64).receive()
    assert len(batch) == len(sent)
    assert batch.lengths.tolist() == [len(d) for d in sent[:-1]] + [64]
    assert batch.truncated.tolist() == [False] * 10 + [True]
    assert [batch.datagram(i) for i in range(len(batch))] == sent[:-1] + [b""]
    assert np.all(np.isfinite(batch.stamps)) and np.all(np.diff(batch.stamps) >= 0)
    assert t_before <= batch.stamps[0] and batch.stamps[-1] <= time.time()


def test_more_datagrams_than_slots_take_several_calls_in_order(pair):
    rx, tx = pair
    for i in range(10):
        tx.send(i.to_bytes(4, "big"))
    _wait_queued(rx)
    receiver = mmsg.MultiReceiver(rx, slots=4, slot_size=16)
    got = []
    while True:
        try:
            batch = receiver.receive()
        except BlockingIOError:
            break
        assert len(batch) <= 4
        got += [int.from_bytes(batch.datagram(i), "big") for i in range(len(batch))]
    assert got == list(range(10))


def test_nobody_listening_is_connection_refused(pair):
    rx, tx = pair
    receiver = mmsg.MultiReceiver(rx, slots=4, slot_size=16)
    tx.close()
    rx.send(b"hello")  # the kernel answers with ICMP port unreachable
    time.sleep(0.05)
    with pytest.raises(ConnectionRefusedError):
        receiver.receive()
