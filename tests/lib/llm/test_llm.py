"""The backend registry of demoforge.lib.llm (get_backend): unknown names list the choices, "fake" comes cached."""

from __future__ import annotations

import pytest

from demoforge.lib.llm import FakeBackend, Sampling, get_backend
from demoforge.lib.llm.cache import CachedBackend
from tests.support.fake_openai import small_prompt


def test_registry(tmp_path):
    with pytest.raises(ValueError) as ei:
        get_backend("gpt-magic")
    assert "fake" in str(ei.value) and "local" in str(ei.value) and "openai" in str(ei.value)
    b = get_backend("fake", responses=["a", "b"], cache_dir=tmp_path)
    assert isinstance(b, CachedBackend) and b.name == "fake"
    assert b.complete(small_prompt(), Sampling()).text == "a"
    assert b.complete(small_prompt(), Sampling()).cached
    assert isinstance(get_backend("FAKE"), FakeBackend)
