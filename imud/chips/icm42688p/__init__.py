"""TDK InvenSense ICM-42688-P (SPI or I2C): banked register map, config model, FIFO packet
driver, register-level simulator.

Facts: docs/chips/icm42688p.md. The registry entry is `imud.chips.icm42688p.spec.SPEC`.
"""
