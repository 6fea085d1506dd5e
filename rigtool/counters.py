"""Names of the transport counters drivers keep, split into ordinary traffic and problems.

Dependency-free, so devices, the engine, the store and the watch page can all use it.
"""

from __future__ import annotations

# Transport counters that count ordinary traffic; every other counter a driver keeps
# (garbage, lost_packets, timeouts, error_frames...) is a problem a reader should see.
TRAFFIC_COUNTERS = frozenset({"frames", "datagrams", "records", "sent", "replies", "heartbeats",
                              "telemetry", "lines", "readings", "queries", "starts", "ignored"})
