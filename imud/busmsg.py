"""Messages between a bus process and the daemon, over one SOCK_SEQPACKET socket (boundaries
kept).

Child to daemon: b"P" + device index (u16) + kind (u8: 0 data, 1 truth, 2 raw) + an encoded batch
(`imud.wire`); b"S" + JSON {"heartbeat_ns": int, "devices": [status, ...]}.
Daemon to child: b"R" + device index (u16) + on (u8): someone started (1) or stopped (0)
subscribing to the device's uncorrected stream.
"""

from __future__ import annotations

import struct

PUBLISH = b"P"
STATUS = b"S"
RAW_WANTED = b"R"
HEADER = struct.Struct("<cHB")
KIND_DATA = 0
KIND_TRUTH = 1
KIND_RAW = 2
KINDS = (KIND_DATA, KIND_TRUTH, KIND_RAW)
RECV_MAX = 1 << 20
