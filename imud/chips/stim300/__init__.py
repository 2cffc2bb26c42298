"""Safran (Sensonor) STIM300: a tactical-grade IMU streaming RS422 datagrams in normal mode."""
