"""Messages between a bus process and the daemon, over one SOCK_SEQPACKET socket (boundaries
kept).

Child to daemon: b"P" + device index (u16) + kind (u8: 0 data, 1 truth, 2 raw) + an encoded batch
(`imud.wire`); b"S" + JSON {"heartbeat_ns": int, "generation": int, "devices": [status, ...]};
b"A" + generation (u32): the device list the daemon sent was applied, and from here on device
indices and statuses are the new list's.
Daemon to child: b"R" + device index (u16) + on (u8): someone started (1) or stopped (0)
subscribing to the device's uncorrected stream; b"C" + JSON {"config": ...}: a reloaded config
(the child keeps its bus's unchanged devices running and applies the rest).
"""

from __future__ import annotations

import struct

PUBLISH = b"P"
STATUS = b"S"
RAW_WANTED = b"R"
RECONFIGURE = b"C"
APPLIED = b"A"
GENERATION = struct.Struct("<I")
HEADER = struct.Struct("<cHB")
KIND_DATA = 0
KIND_TRUTH = 1
KIND_RAW = 2
KINDS = (KIND_DATA, KIND_TRUTH, KIND_RAW)
RECV_MAX = 1 << 20
