"""Orientation: a bias-aware error-state Kalman filter run on NumPy batches (imud.orient.ekf)."""
