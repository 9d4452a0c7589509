"""Model files that break the JSON parser or are far too big (issue 26, part 5): a ConfigError
naming the file, never a RecursionError/ValueError traceback or an unbounded read."""

from __future__ import annotations

from pathlib import Path

import pytest

from hystbench.compensator import models
from hystbench.compensator.models import ModelSet
from hystbench.errors import ConfigError


@pytest.mark.parametrize("text, why", [
    ("[" * 100_000 + "]" * 100_000, "RecursionError"),  # before: a RecursionError traceback
    ('{"format": ' + "1" * 5000 + "}", "ValueError"),  # before: int()'s digit limit, a ValueError traceback
])
def test_model_files_that_break_the_parser_are_named(tmp_path: Path, text: str, why: str) -> None:
    path = tmp_path / "m.json"
    path.write_text(text)
    with pytest.raises(ConfigError, match=rf"^{path}: not a model file \({why}"):
        ModelSet.load(path)


def test_a_model_file_past_max_model_bytes_is_refused_unread(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "m.json"
    path.write_text('{"format": "x", "pad": "' + "p" * 2000 + '"}')
    monkeypatch.setattr(models, "MAX_MODEL_BYTES", 1000)
    with pytest.raises(ConfigError, match=rf"^{path}: larger than 1000 bytes, not a model file"):
        ModelSet.load(path)
    monkeypatch.setattr(models, "MAX_MODEL_BYTES", 4000)
    with pytest.raises(ConfigError, match="not a hystbench model file"):  # read, then judged on its content
        ModelSet.load(path)
