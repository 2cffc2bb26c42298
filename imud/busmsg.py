"""Messages from a bus process to the daemon, over one SOCK_SEQPACKET socket (boundaries kept).

b"P" + device index (u16) + kind (u8: 0 data, 1 truth) + an encoded batch (`imud.wire`);
b"S" + JSON {"heartbeat_ns": int, "devices": [status, ...]}.
"""

from __future__ import annotations

import struct

PUBLISH = b"P"
STATUS = b"S"
HEADER = struct.Struct("<cHB")
KIND_DATA = 0
KIND_TRUTH = 1
RECV_MAX = 1 << 20
