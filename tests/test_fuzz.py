"""The fuzz targets of fuzz/fuzz_swarmd.py under hypothesis: bounded example counts,
derandomized (the "ci" profile of conftest.py), so CI is fast and repeatable. Long runs
use atheris on the same targets (docs/testing.md)."""

from __future__ import annotations

import json

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from fuzz.fuzz_swarmd import (
    TARGETS,
    target_config,
    target_decoder,
    target_link_line,
    target_state,
    target_state_json,
)
from swarmd.core import wire

EXAMPLES = settings(max_examples=100, deadline=None)

# JSON values with big and nested numbers where the loaders feel them.
json_values = st.recursive(
    st.none() | st.booleans() | st.integers(min_value=-(1 << 70), max_value=1 << 70)
    | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4)
    | st.dictionaries(st.text(max_size=4), children, max_size=4),
    max_leaves=6,
)


@EXAMPLES
@given(st.binary(max_size=96))
@example(b"")
@example(bytes([wire.VERSION << 4]) + b"\x00" * 40)
def test_fuzz_decoder(data: bytes) -> None:
    target_decoder(data)


@EXAMPLES
@given(st.binary(max_size=200))
@example(b"[" * 100_000)
@example(b'{"seq_reserved": ' + b"7" * 5000 + b"}")
def test_fuzz_state_bytes(data: bytes) -> None:
    target_state(data)


@EXAMPLES
@given(st.fixed_dictionaries({}, optional={
    "known": st.dictionaries(st.sampled_from(["f1", "f2", "f9", ""]),
                             st.lists(json_values, max_size=3), max_size=3) | json_values,
    "held": st.lists(json_values, max_size=3) | json_values,
    "seq_reserved": json_values | st.integers(min_value=(1 << 48) - 10**6 - 2,
                                              max_value=1 << 49),
}))
def test_fuzz_state_fields(fields: dict[str, object]) -> None:
    body = json.dumps(fields)[1:]  # the target supplies the object's opening
    target_state_json(body.encode() if body != "}" else b'"known": {}}')


yaml_bits = st.sampled_from([
    "swarm: {id: 1}\n", "functions: {f1: {kind: slot, position: [0, 0, 1]}}\n",
    "robots: [{id: 1, state: active}]\n", "&a [x, x]\n", "*a\n", "b: &b [*a, *a]\n",
    "[", "]", "{", "}", "- ", "  ", ": ", "id: true\n", "id: 99999999999999999999\n",
    "timing: {t_max: 1.0e308}\n", "\t", "'", '"', "#", "\n", "? ", "!!python/object ",
])


@EXAMPLES
@given(st.lists(yaml_bits, max_size=30).map("".join) | st.text(max_size=200))
@example("swarm: " + "[" * 30000 + "]" * 30000)
def test_fuzz_config(text: str) -> None:
    target_config(text.encode())


@EXAMPLES
@given(st.binary(max_size=200) | st.builds(
    lambda v: json.dumps({"health": v}).encode(), json_values))
@example(b"[" * 60000)
@example(b'{"health": ' + b"9" * 5000 + b"}")
@example(b'{"health": "ok"}')
def test_fuzz_link_line(data: bytes) -> None:
    target_link_line(data)


@pytest.mark.parametrize("name", sorted(TARGETS))
def test_every_fuzz_target_accepts_empty_and_junk(name: str) -> None:
    for data in (b"", b"\x00\xff" * 8, b"{}", b"[]"):
        TARGETS[name](data)
