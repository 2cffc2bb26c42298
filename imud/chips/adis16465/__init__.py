"""ADIS16465 (Analog Devices): SPI with 16-bit words, a checksummed burst read, a data counter,
delta-angle and delta-velocity outputs (docs/chips/adis16465.md)."""
