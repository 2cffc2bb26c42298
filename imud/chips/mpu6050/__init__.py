"""InvenSense MPU6050 (I2C): register map, config model, FIFO driver, register-level simulator.

Facts: docs/chips/mpu6050.md. The registry entry is `imud.chips.mpu6050.spec.SPEC`.
"""
