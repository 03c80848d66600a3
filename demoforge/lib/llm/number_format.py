"""How the numbers of a prompt are written: the thesis's metres, or a compact integer format.

Gemma's tokenizer splits numbers into single digits, so a pose costs about one token per digit, sign,
point and comma: ``[0.412,-0.103,0.221,0,0.707,0,0.707,1]`` is 37 tokens. Writing positions in whole
millimetres and quaternion components in hundredths drops the ``0.`` of every number:
``[412,-103,221,0,71,0,71,1]`` is 25 tokens, with 0.5 mm and about 0.6 degrees of rounding.

* ``thesis``  (default): metres and unit quaternions, rounded to the prompt's ``precision``
  decimals (Appendix A's layout).
* ``compact``: positions in mm, quaternion components x 100, both rounded to integers; one sentence
  added to the system prompt says so. An answer is read back with :meth:`NumberFormat.decode_poses`
  (the parser already normalises quaternions, so only the positions need rescaling).

Conventions: a pose is 8 values (x, y, z in the world frame, quaternion w, x, y, z, gripper open 1 /
closed 0; docs/architecture.md), keypoints are (k, 3) world positions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["NumberFormat", "NUMBER_FORMATS", "DEFAULT_NUMBER_FORMAT", "get_number_format"]


@dataclass(frozen=True)
class NumberFormat:
    name: str
    position_scale: float  # written value = metres x this
    rotation_scale: float  # written value = quaternion component x this
    decimals: int | None  # None: the prompt's own precision; else fixed (0: integers)
    system_note: str  # appended to the system prompt ("" keeps Appendix A word for word)
    int_digits: int  # most digits before the point an answer needs (bounds the structured grammar)

    def precision(self, requested: int) -> int:
        return int(requested) if self.decimals is None else self.decimals

    def _scales(self, width: int) -> np.ndarray:
        s = np.ones(width)
        s[:3] = self.position_scale
        if width == 8:
            s[3:7] = self.rotation_scale
        return s

    def encode_points(self, points: np.ndarray) -> np.ndarray:
        """(k, 3) world positions (m) as written."""
        return np.asarray(points, dtype=np.float64) * self.position_scale

    def encode_poses(self, poses: np.ndarray) -> np.ndarray:
        """(..., 8) poses as written (the gripper state is left as it is)."""
        p = np.asarray(poses, dtype=np.float64)
        if p.shape[-1] != 8:
            raise ValueError(f"poses must end in 8 values, got shape {p.shape}")
        return p * self._scales(8)

    def decode_poses(self, written: np.ndarray) -> np.ndarray:
        """(..., 8) values as the model wrote them -> metres and unit quaternions."""
        p = np.array(written, dtype=np.float64)
        if p.shape[-1] != 8:
            raise ValueError(f"poses must end in 8 values, got shape {p.shape}")
        p[..., :3] /= self.position_scale
        q = p[..., 3:7]
        norm = np.linalg.norm(q, axis=-1, keepdims=True)
        p[..., 3:7] = np.divide(q, norm, out=np.zeros_like(q), where=norm > 0)
        return p


NUMBER_FORMATS = {
    "thesis": NumberFormat("thesis", 1.0, 1.0, None, "", 2),
    "compact": NumberFormat(
        "compact", 1000.0, 100.0, 0,
        "Numbers are integers: positions in millimetres, quaternion components multiplied by 100.", 4),
}
DEFAULT_NUMBER_FORMAT = "thesis"


def get_number_format(name: str | None) -> NumberFormat:
    fmt = NUMBER_FORMATS.get(name or DEFAULT_NUMBER_FORMAT)
    if fmt is None:
        raise ValueError(f"number format must be one of {', '.join(NUMBER_FORMATS)}, got {name!r}")
    return fmt
