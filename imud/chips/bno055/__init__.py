"""Bosch BNO055 (I2C or UART, on-chip fusion): register map, UART protocol, config model,
polled burst driver with calibration-offset persistence, register-level simulator.

Facts: docs/chips/bno055.md. The registry entry is `imud.chips.bno055.spec.SPEC`.
"""
