"""The semantic channels of a field and the category ids they stand for."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class LabelSpace:
    """The semantic channels of the field: channel 0 is void (never a training target, never predicted),
    channel ``k ≥ 1`` is category ``semantic_ids[k - 1]``."""

    semantic_ids: list[int]
    thing_ids: list[int]

    @property
    def num_channels(self) -> int:
        return len(self.semantic_ids) + 1

    def category_to_channel(self) -> np.ndarray:
        """Lookup table ``category id → channel`` (0 for void and unknown ids)."""
        lut = np.zeros(max(self.semantic_ids + [0]) + 1, np.int16)
        lut[self.semantic_ids] = np.arange(1, len(self.semantic_ids) + 1)
        return lut

    def channel_to_category(self) -> np.ndarray:
        """``[U]`` category id per channel (0 for the void channel)."""
        return np.asarray([0] + list(self.semantic_ids), np.int64)

    def thing_channels(self) -> np.ndarray:
        """``[U]`` bool: channel is a thing class."""
        return np.isin(self.channel_to_category(), self.thing_ids) & (self.channel_to_category() > 0)

    def to_dict(self) -> dict:
        return {"semantic_ids": list(map(int, self.semantic_ids)), "thing_ids": list(map(int, self.thing_ids))}

    @classmethod
    def from_dict(cls, d: dict) -> "LabelSpace":
        return cls([int(x) for x in d["semantic_ids"]], [int(x) for x in d["thing_ids"]])
