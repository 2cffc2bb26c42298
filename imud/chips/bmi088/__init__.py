"""Bosch BMI088 (SPI or I2C): two dies (accel, gyro) on one bus, configured and published as one
device; register maps, FIFO decoding, die pairing, config model, driver, simulators.

Facts: docs/chips/bmi088.md. The registry entry is `imud.chips.bmi088.spec.SPEC`.
"""
