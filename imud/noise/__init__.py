"""Noise analysis: Allan deviation of rate samples, streamed (imud/noise/allan.py)."""
