"""Physical constants every layer uses, defined once."""

from __future__ import annotations

# standard gravity (CGPM 1901; ISO 80000-3): what datasheets mean by "g", m/s^2. Local gravity
# differs by up to 0.27 % (imud.calib.gravity)
STANDARD_GRAVITY = 9.80665
