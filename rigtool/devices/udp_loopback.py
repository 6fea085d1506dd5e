"""A python-can bus over UDP multicast that never leaves this host (interface `udp_loopback`).

python-can's `udp_multicast` binds every interface and joins its group on the LAN, so
anything on the network can send it frames, and every bus on the same group and port
hears every other. This bus is the same wire format (msgpack frames) but bound to its own
group address, joined on the loopback interface only (and not fed other groups' traffic),
and it sends with TTL 0 through loopback. `rigtool sim` serves its CAN personalities on
one with a fresh channel per instance; the CAN drivers open it from the rig file.

Channel: `GROUP:PORT`, GROUP an IPv4 multicast address in 239.0.0.0/8 (Linux).
"""

from __future__ import annotations

import ipaddress
import random
import socket
import struct
from typing import Any

from can import BusABC, CanProtocol
from can.interfaces.udp_multicast.bus import GeneralPurposeUdpMulticastBus, UdpMulticastBus
from can.interfaces.udp_multicast.utils import is_msgpack_installed

INTERFACE = "udp_loopback"
LOOPBACK = "127.0.0.1"
ADMIN_SCOPE = ipaddress.ip_network("239.0.0.0/8")
_IP_MULTICAST_ALL = getattr(socket, "IP_MULTICAST_ALL", 49)  # Linux; not in every Python build
_SO_TIMESTAMPNS = 35


def parse_channel(channel: str) -> tuple[str, int]:
    """'239.1.2.3:45000' -> ('239.1.2.3', 45000); ValueError saying what is wrong."""
    group, sep, port = channel.rpartition(":")
    try:
        address = ipaddress.IPv4Address(group)
        number = int(port)
    except ValueError:
        raise ValueError(f"expected GROUP:PORT with GROUP in {ADMIN_SCOPE}, got {channel!r}") from None
    if not sep or address not in ADMIN_SCOPE or not 1 <= number <= 65535:
        raise ValueError(f"expected GROUP:PORT with GROUP in {ADMIN_SCOPE} and PORT in "
                         f"1..65535, got {channel!r}")
    return group, number


def new_channel(group: str | None = None) -> str:
    """A fresh `GROUP:PORT`: a random group in 239.0.0.0/8 (unless given) and a free UDP port."""
    if group is None:
        rng = random.SystemRandom()
        group = f"239.{rng.randrange(256)}.{rng.randrange(256)}.{rng.randrange(1, 255)}"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind((LOOPBACK, 0))
        port = probe.getsockname()[1]
    return f"{group}:{port}"


class _LoopbackMulticast(GeneralPurposeUdpMulticastBus):
    """python-can's multicast socket handler, with a socket that stays on loopback."""

    def _create_socket(self, address_family: socket.AddressFamily) -> socket.socket:
        if address_family != socket.AF_INET:
            raise OSError("udp_loopback is IPv4 only")
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, struct.pack("@I", 0))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(LOOPBACK))
            sock.setsockopt(socket.IPPROTO_IP, _IP_MULTICAST_ALL, 0)
            # the simulator, a sweep and a `check` on one host share the group
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            try:
                sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
                self.timestamp_nanosecond = True
            except OSError:
                self.timestamp_nanosecond = False
            sock.bind((self.group, self.port))  # only datagrams sent to the group arrive
            membership = socket.inet_aton(self.group) + socket.inet_aton(LOOPBACK)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)
        except OSError:
            sock.close()
            raise
        return sock


class UdpLoopbackBus(UdpMulticastBus):
    """python-can's UdpMulticastBus on a loopback-only socket; channel `GROUP:PORT`."""

    def __init__(self, channel: str, fd: bool = True, **kwargs: Any) -> None:
        group, port = parse_channel(channel)
        is_msgpack_installed()
        BusABC.__init__(self, channel, **kwargs)
        self._multicast = _LoopbackMulticast(group, port, hop_limit=0)
        self._can_protocol = CanProtocol.CAN_FD if fd else CanProtocol.CAN_20
