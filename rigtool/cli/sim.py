"""`rigtool sim`: run the simulator twin on real transports and print its rig file."""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading

from rigtool.cli.console import err, out


def add_parsers(sub: argparse._SubParsersAction) -> None:
    from rigtool.sim.personalities import SENSORS
    from rigtool.thruster_profiles import PROFILES

    p = sub.add_parser("sim", help="run the simulator twin on real transports and print its rig file")
    p.add_argument("--profile", default="stm32-pwm", help=" | ".join(PROFILES))
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--sensor", default="netft", help=" | ".join(SENSORS))
    p.add_argument("--bind", default="127.0.0.1", metavar="ADDRESS",
                   help="address the network personalities serve on (default 127.0.0.1: this "
                        "host only; e.g. 0.0.0.0 makes the simulator reachable from the LAN)")
    p.add_argument("--netft", metavar="[HOST:]PORT",
                   help="where the Net F/T answers (default: the --bind address, port 49152; "
                        "port 0: any free port)")
    p.add_argument("--can-channel", metavar="GROUP[:PORT]",
                   help="multicast group (239.x.y.z) of the CAN personalities' bus (default: a "
                        "random group and a free port, so every simulator has its own bus)")
    p.add_argument("--depth", type=float, default=1.0, help="initial propeller depth (m)")
    p.add_argument("--rate", type=float, default=1000.0, metavar="HZ",
                   help="samples per second of the twin, and the Net F/T's RDT rate (default "
                        "1000; the real box goes up to 7000)")
    p.add_argument("--fault", action="append", metavar="PART.SWITCH=VALUE",
                   help="inject a fault, e.g. netft.drop=0.01, netft.silent=true, bridge.garbage=true, "
                        "bridge.no_replies=true, vesc.fault_code=4, vesc.deaf=true, stage.stalled=true "
                        "(repeatable)")
    p.add_argument("--rig-out", help="also write the rig file here")
    p.set_defaults(func=cmd_sim)


def cmd_sim(args: argparse.Namespace) -> int:
    from rigtool.sim.server import start_sim

    server = start_sim(args.profile, seed=args.seed, sensor=args.sensor, netft=args.netft,
                       can_channel=args.can_channel, depth_m=args.depth, bind=args.bind,
                       rate_hz=args.rate)
    try:
        for spec in args.fault or ():
            server.set_fault(spec)
    except BaseException:
        server.stop()
        raise
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, lambda *_: stop.set())
    try:
        text = server.rig_yaml()
        if args.rig_out:
            tmp = f"{args.rig_out}.tmp"
            with open(tmp, "w", encoding="utf-8") as fh:
                fh.write(text)
            os.replace(tmp, args.rig_out)
            err.print(f"rig file written to {args.rig_out}")
        for warning in server.exposure():
            err.print(f"warning: {warning}")
        out.print(f"# rigtool sim --profile {args.profile}: use this rig file "
                  "(rigtool sweep PROTOCOL --rig FILE); Ctrl-C stops the simulator")
        out.print(text)
        sys.stdout.flush()
        stop.wait()
    finally:
        server.stop()
    return 0
