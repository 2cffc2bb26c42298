"""Register bit fields: what register maps are made of (kept free of heavy imports)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class BitField:
    """A multi-bit field of a register, by its mask (e.g. 0x18 for bits [4:3])."""

    mask: int

    @property
    def shift(self) -> int:
        return (self.mask & -self.mask).bit_length() - 1

    def bits(self, value: int) -> int:
        """The field holding `value`, in place."""
        out = (value << self.shift) & self.mask
        if out >> self.shift != value:
            raise ValueError(f"{value} does not fit the field 0x{self.mask:02x}")
        return out

    def get(self, register_value: int) -> int:
        return (register_value & self.mask) >> self.shift
