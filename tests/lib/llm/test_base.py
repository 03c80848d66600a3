"""The backends' shared types (demoforge.lib.llm.base): sampling settings are frozen, hashable and checked."""

from __future__ import annotations

import pytest

from demoforge.lib.llm.base import Sampling


def test_sampling_is_frozen_and_hashable():
    s = Sampling(stop=["\n#", "**"])
    assert s.stop == ("\n#", "**") and hash(s) == hash(Sampling(stop=("\n#", "**")))
    with pytest.raises(Exception):
        s.seed = 3  # type: ignore[misc]
    with pytest.raises(ValueError):
        Sampling(max_tokens=0)
