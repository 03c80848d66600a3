"""The compact number format: what is written reads back within its rounding, and costs fewer tokens."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.extra.numpy import arrays

from demoforge.lib.geometry import quat_angle, quat_normalize
from demoforge.lib.llm.number_format import NUMBER_FORMATS, get_number_format
from demoforge.lib.llm.prompting import approx_token_count, format_actions

COMPACT = NUMBER_FORMATS["compact"]


def _poses(raw: np.ndarray) -> np.ndarray:
    p = raw.copy()
    p[..., 3:7] = quat_normalize(p[..., 3:7] + np.array([1.0, 0, 0, 0]) * (np.linalg.norm(p[..., 3:7], axis=-1,
                                                                                         keepdims=True) < 1e-3))
    p[..., 7] = (p[..., 7] > 0).astype(float)
    return p


@settings(max_examples=60)
@given(arrays(np.float64, (5, 2, 8), elements=st.floats(-0.9, 0.9, allow_nan=False)))
def test_compact_reads_back_within_its_rounding(raw):
    poses = _poses(raw)
    written = np.round(COMPACT.encode_poses(poses))  # what the prompt shows (integers)
    back = COMPACT.decode_poses(written)
    assert np.abs(back[..., :3] - poses[..., :3]).max() <= 0.0005 + 1e-12  # half a millimetre
    # hundredths of each component: the rotation is off by at most ~0.6 degrees
    assert quat_angle(back[..., 3:7], poses[..., 3:7]).max() < 0.025
    assert np.array_equal(back[..., 7], poses[..., 7])


def test_thesis_format_writes_metres_unchanged():
    fmt = get_number_format(None)
    poses = _poses(np.random.default_rng(0).uniform(-0.5, 0.5, (3, 2, 8)))
    assert fmt.name == "thesis" and fmt.precision(3) == 3 and fmt.system_note == ""
    assert np.array_equal(fmt.encode_poses(poses), poses)
    assert np.allclose(fmt.decode_poses(poses), poses)


def test_compact_costs_fewer_tokens_than_the_thesis_format():
    poses = _poses(np.random.default_rng(1).uniform(-0.5, 0.5, (20, 2, 8)))
    thesis = approx_token_count(format_actions(poses, 3))
    compact = approx_token_count(format_actions(COMPACT.encode_poses(poses), COMPACT.precision(3)))
    assert compact < 0.75 * thesis, (compact, thesis)


def test_unknown_format_is_refused_with_the_choices():
    with pytest.raises(ValueError, match="thesis, compact"):
        get_number_format("hex")
