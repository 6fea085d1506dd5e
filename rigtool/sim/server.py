"""`rigtool sim`: the physics twin in real time behind device personalities on real transports.

Starts one LiveTwin and, for the chosen profile, the actuator personality, a force
sensor personality and a depth stage, then describes them as a rig file that the real
drivers can use unchanged.
"""

from __future__ import annotations

import ipaddress
import socket
from dataclasses import dataclass, field

import yaml

from rigtool.devices import udp_loopback
from rigtool.errors import UsageError
from rigtool.sim.live import LiveTwin
from rigtool.sim.personalities import SENSORS
from rigtool.sim.physics import ThrusterTwin
from rigtool.thruster_profiles import profile_with_overrides

LOOPBACK = "127.0.0.1"
NETFT_PORT = 49152
STAGE_ZERO_OFFSET_M = 0.1  # stage position (m) at which the propeller centre is at the surface


def parse_host_port(text: str, default_host: str = LOOPBACK) -> tuple[str, int]:
    """HOST:PORT or PORT -> (host, port); port 0 picks a free one."""
    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        raise UsageError(f"expected HOST:PORT, got {text!r}") from None
    if not 0 <= number <= 65535:
        raise UsageError(f"port {number} is out of range 0..65535")
    return host or default_host, number


def resolve_bind(bind: str) -> tuple[str, bool]:
    """The IPv4 address `--bind` names, and whether it is a loopback address."""
    try:
        address = socket.gethostbyname(bind)
    except (OSError, UnicodeError):
        raise UsageError(f"--bind {bind!r}: not an IPv4 address or a known host name") from None
    return address, ipaddress.ip_address(address).is_loopback


@dataclass
class SimServer:
    """Running personalities and the rig file that reaches them."""

    live: LiveTwin
    parts: dict = field(default_factory=dict)  # name -> personality
    rig: dict = field(default_factory=dict)

    def rig_yaml(self) -> str:
        return yaml.safe_dump(self.rig, sort_keys=False)

    def stop(self) -> None:
        for part in reversed(list(self.parts.values())):
            part.stop()
        self.live.stop()

    def exposure(self) -> list[str]:
        """Warnings for every personality reachable from beyond this host."""
        out = []
        for part, section in (("actuator", self.rig.get("actuator", {})),
                              ("sensor", self.rig.get("sensor", {}))):
            host = section.get("host") or section.get("url", "")
            if section.get("interface") == "udp_multicast":
                out.append(f"{part}: CAN bus on python-can udp_multicast {section['channel']}: "
                           "reachable from the LAN")
            elif host and not any(h in host for h in (LOOPBACK, "localhost", "/dev/")):
                out.append(f"{part}: serving on {host}: reachable from the network")
        return out

    def set_fault(self, spec: str) -> None:
        """Apply `PART.SWITCH=VALUE`, e.g. `netft.drop=0.01`, `bridge.garbage=true`, `vesc.fault_code=4`."""
        target, _, value = spec.partition("=")
        name, _, switch = target.partition(".")
        part = self.parts.get(name)
        if part is None or not switch or not value:
            raise UsageError(f"--fault {spec!r}: expected PART.SWITCH=VALUE with PART one of "
                             f"{', '.join(self.parts)}")
        obj = part.faults if hasattr(part, "faults") and hasattr(part.faults, switch) else part
        if switch.startswith("_") or not hasattr(obj, switch):
            raise UsageError(f"--fault {spec!r}: {name} has no fault switch {switch!r}")
        current = getattr(obj, switch)
        if not isinstance(current, bool | int | float | str):
            raise UsageError(f"--fault {spec!r}: {name}.{switch} is not a fault switch")
        if isinstance(current, bool) and value.lower() not in ("1", "0", "true", "false", "yes", "no", "on", "off"):
            raise UsageError(f"--fault {spec!r}: expected true or false")
        try:
            parsed = (value.lower() in ("1", "true", "yes", "on")) if isinstance(current, bool) \
                else type(current)(value)
        except (TypeError, ValueError):
            raise UsageError(f"--fault {spec!r}: {value!r} is not a valid {type(current).__name__}") from None
        setattr(obj, switch, parsed)


def start_sim(profile_name: str, seed: int = 1, sensor: str = "netft",
              netft: str | None = None, can_channel: str | None = None,
              depth_m: float = 1.0, bind: str = LOOPBACK, rate_hz: float = 1000.0) -> SimServer:
    """Start the twin and its personalities; the caller must stop() the result.

    Every network personality serves on `bind` (loopback by default, so nothing on the LAN
    reaches the simulator); `netft` (HOST:PORT or PORT) overrides it for the Net F/T. The
    CAN personality gets its own channel (`can_channel`: GROUP or GROUP:PORT, else random).
    The twin runs at `rate_hz` samples per second (the Net F/T's RDT rate).
    """
    from rigtool.sim.gauge_twin import GaugeTwin
    from rigtool.sim.netft_twin import NetFTTwin
    from rigtool.sim.stage_twin import StageTwin
    from rigtool.sim.stm32_twin import Stm32BridgeTwin

    if sensor not in SENSORS:
        raise UsageError(f"unknown sensor personality {sensor!r}; choose one of {', '.join(SENSORS)}")
    host, loopback = resolve_bind(bind)
    profile = profile_with_overrides(profile_name, {})
    if not 1.0 <= rate_hz <= 10_000.0:
        raise UsageError(f"--rate {rate_hz:g}: the twin runs at 1 to 10000 samples/s")
    live = LiveTwin(ThrusterTwin(profile, seed=seed, depth_m=depth_m), rate_hz=rate_hz).start()
    server = SimServer(live)
    try:
        rig: dict = {"rigtool_rig": 1, "name": f"rigtool-sim-{profile.name}",
                     "description": "personalities started by `rigtool sim`"}
        if profile.command_unit == "percent":
            rig["actuator"] = _start_can(server, can_channel, loopback)
        else:
            bridge = Stm32BridgeTwin(live, host=host).start()
            server.parts["bridge"] = bridge
            rig["actuator"] = {"driver": "stm32-bridge", "url": bridge.url,
                               "command_unit": profile.command_unit,
                               "psc": bridge.psc, "arr": bridge.arr}
        preset = SENSORS[sensor]
        if preset is None:
            ft_host, port = parse_host_port(netft or str(NETFT_PORT), host)
            try:
                ft = NetFTTwin(live, ft_host, port, seed=seed).start()
            except OSError as exc:
                raise UsageError(f"cannot serve Net F/T on {ft_host}:{port}: {exc} "
                                 "(choose another with --netft HOST:PORT, or port 0)") from None
            server.parts["netft"] = ft
            h, p = ft.address
            rig["sensor"] = {"driver": "ati-netft", "host": h, "port": p, "http_port": ft.http_port}
        else:
            gauge = GaugeTwin(live, preset, seed=seed).start()
            server.parts["gauge"] = gauge
            rig["sensor"] = {"driver": "ascii-gauge", "url": gauge.port, "preset": preset,
                             "channel": ("fx", "fy", "fz")[gauge.channel], **gauge.rig_fields()}
        stage = StageTwin(live, zero_offset_m=STAGE_ZERO_OFFSET_M,
                          position_mm=(depth_m + STAGE_ZERO_OFFSET_M) * 1000).start()
        server.parts["stage"] = stage
        rig["depth_stage"] = {"driver": "serial-stage", "url": stage.pty_path,
                              "speed_mm_s": stage.speed_mm_s, "zero_offset_m": STAGE_ZERO_OFFSET_M}
        ch = ("fx", "fy", "fz", "tx", "ty", "tz")[profile.thrust_channel]
        rig["thrust"] = {"channel": ch, "sign": profile.thrust_sign}
        server.rig = rig
    except BaseException:
        server.stop()
        raise
    return server


def _start_can(server: SimServer, channel: str | None, loopback: bool) -> dict:
    """A VESC on a CAN bus of its own: loopback-only unless the sim binds another address."""
    from rigtool.sim.vesc_twin import VescTwin

    if loopback:
        interface, channel = udp_loopback.INTERFACE, _loopback_channel(channel)
    else:  # python-can's udp_multicast: every interface, the LAN, its fixed port
        interface, channel = "udp_multicast", _lan_group(channel)
    vesc = VescTwin(server.live, channel=channel, interface=interface).start()
    server.parts["vesc"] = vesc
    return {"driver": "vesc-can", **vesc.address}


def _loopback_channel(channel: str | None) -> str:
    """GROUP:PORT for a udp_loopback bus: as given, or a fresh port (and group)."""
    try:
        if channel and ":" in channel:
            udp_loopback.parse_channel(channel)
            return channel
        return udp_loopback.new_channel(_lan_group(channel) if channel else None)
    except ValueError as exc:
        raise UsageError(f"--can-channel: {exc}") from None


def _lan_group(channel: str | None) -> str:
    """A multicast group for python-can's udp_multicast: as given, or a random one."""
    if channel is None:
        return udp_loopback.new_channel().rpartition(":")[0]
    try:
        if ipaddress.IPv4Address(channel) in udp_loopback.ADMIN_SCOPE:
            return channel
    except ValueError:
        pass
    raise UsageError(f"--can-channel {channel!r}: expected a multicast group in "
                     f"{udp_loopback.ADMIN_SCOPE} (with --bind other than loopback, no :PORT)")
