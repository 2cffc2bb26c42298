"""Calibration: the sensor models applied live, the files that hold them, and the procedures
that estimate them (live against the daemon, or offline from recordings)."""
