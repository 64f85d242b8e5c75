"""An MCAP whose message schema cannot be used is never decoded by a silent guess (tracker issue 29, item 4).

The hostile corpus's two cases (``scripts/make_hostile_corpus.py``): ``std_msgs/msg/Float64`` defined
as containing itself, and as holding a type the file never defines. The bytes are the standard type's,
so decoding them by the standard definition gives the clean file's numbers; the reader must say that
it did so, once, in the reader's warnings (the terminal and the JSON's ``warnings``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from make_hostile_corpus import build_corpus  # noqa: E402

from mrftcli.errors import LogReadError  # noqa: E402
from mrftcli.io import open_log  # noqa: E402
from mrftcli.io.format_mcap import McapSource, channel_typestore  # noqa: E402

CASES = {"mcap_self_schema.mcap": "contains itself", "mcap_unknown_type.mcap": "nowhere_msgs/msg/Ghost is not defined"}


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("schemas") / "corpus"
    build_corpus(out, only=r"^(mcap_self_schema|mcap_unknown_type)\.mcap$")
    return out


@pytest.mark.parametrize("name", list(CASES))
def test_a_broken_schema_is_decoded_by_the_standard_type_and_said_once(corpus: Path, name: str) -> None:
    with open_log(ROOT / "sample_logs" / "design1_altitude.mcap") as clean:
        want = [clean.series(topic) for topic in ("/mrft/command", "/mrft/beta")]
    with open_log(corpus / name, echo_warnings=False) as log:
        got = [log.series(topic) for topic in ("/mrft/command", "/mrft/beta")]
        said = [w for w in log.warnings if "schema" in w]
    for a, b in zip(want, got):
        np.testing.assert_array_equal(a.t, b.t)
        np.testing.assert_array_equal(a.values, b.values)
    assert len(said) == 1, log.warnings  # two channels share the schema: one warning
    assert CASES[name] in said[0] and "decoded with the standard std_msgs/msg/Float64 definition" in said[0]


def test_without_a_place_to_say_it_the_broken_schema_is_refused(corpus: Path) -> None:
    with McapSource(corpus / "mcap_self_schema.mcap") as log:
        ch = next(c for c in log._channels.values() if c.topic == "/mrft/command")
        with pytest.raises(LogReadError, match="schema for std_msgs/msg/Float64 is unusable.*cannot be decoded"):
            channel_typestore(ch, log.path)
