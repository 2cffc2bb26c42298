"""Real-time scheduling for the threads that must not be late: bus workers and the publisher."""

from __future__ import annotations

import logging
import os

log = logging.getLogger("imud.rt")


def go_realtime(priority: int, who: str) -> bool:
    """SCHED_FIFO at `priority` for the calling thread (and the threads it creates later).
    Returns False, with one warning saying how to grant it, when the system refuses."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as e:
        log.warning(
            "%s: cannot run SCHED_FIFO at priority %d (%s): grant CAP_SYS_NICE or "
            "LimitRTPRIO=%d or more (the systemd unit sets 20), or run as root; continuing "
            "without",
            who,
            priority,
            e.strerror,
            priority,
        )
        return False
    log.info("%s: SCHED_FIFO at priority %d", who, priority)
    return True
