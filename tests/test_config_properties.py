"""Property-based: whatever the configuration is given, the result is a Config or a one-line
ConfigError that names the key, never another exception (Hypothesis generates the input)."""

from __future__ import annotations

import contextlib
import io
import math
import os
import tempfile

import tomli_w
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from armvision import cli
from armvision.config import (
    Config,
    apply_override,
    config_from_dict,
    config_to_toml,
    known_keys,
    load_config,
)
from armvision.errors import ConfigError

KEYS = known_keys()
SECTIONS = sorted({key.split(".")[0] for key in KEYS})
FAST = settings(deadline=None, max_examples=150, suppress_health_check=[HealthCheck.too_slow])

HUGE_INTS = st.sampled_from([2**63, -(2**63) - 1, 10**30, -(10**30)]) | st.integers(4300, 4400).map(
    lambda digits: 10**digits
)  # more digits than Python turns into a string
SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(),
    HUGE_INTS,
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([math.inf, -math.inf, math.nan, 1e300, -1e300, 5e-324, -0.0]),
    st.text(max_size=12),
    st.sampled_from(["", "\x00", "a\nb", "\udcff", "tag36h11", "cv", "127.0.0.1"]),
    st.datetimes(),
    st.dates(),
)
# JSON-ish values, nested: lists and tables of anything.
VALUES = st.recursive(
    SCALARS,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=8,
)
# Values of the right kind more often, so some examples get past the type checks to the ranges.
NUMBERS = st.one_of(
    st.integers(-5, 5000),
    st.floats(-10.0, 2000.0),
    st.lists(st.floats(-1.0, 1.0), min_size=1, max_size=4),
)


def _nest(assignments: list[tuple[str, object]]) -> dict:
    """{"a.b": v} -> {"a": {"b": v}}; an assignment under a key that holds a value is dropped."""
    data: dict = {}
    for key, value in assignments:
        *parents, leaf = key.split(".")
        node = data
        for part in parents:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                break
            node = child
        else:
            node[leaf] = value
    return data


ASSIGNMENTS = st.lists(
    st.tuples(st.sampled_from(KEYS) | st.text(max_size=10), VALUES | NUMBERS), max_size=8
)
JUNK = st.dictionaries(
    st.sampled_from(SECTIONS) | st.text(max_size=8),
    VALUES | st.dictionaries(st.sampled_from(KEYS) | st.text(max_size=8), VALUES),
    max_size=4,
)


def _outcome(fn, names: str = "'") -> Config | str:
    """A valid Config, or the ConfigError's message after checking it is one line that names
    what is wrong (by default a quoted key, an unknown key or the override)."""
    try:
        config = fn()
    except ConfigError as exc:
        message = str(exc)
        assert message and "\n" not in message and "\r" not in message, repr(message)
        assert message.isprintable(), repr(message)
        assert names in message, message
        return message
    assert isinstance(config, Config)
    return config


@FAST
@given(ASSIGNMENTS)
def test_generated_dicts_give_a_config_or_one_line_error(assignments):
    data = _nest(assignments)
    result = _outcome(lambda: config_from_dict(data))
    if isinstance(result, Config):  # then every key given is known (a typo never passes)
        for section, table in data.items():
            assert section in SECTIONS
            assert all(f"{section}.{key}" in KEYS for key in table)


@FAST
@given(JUNK)
def test_nested_junk_gives_a_config_or_one_line_error(data):
    _outcome(lambda: config_from_dict(data))


@FAST
@given(st.sampled_from(KEYS), VALUES | NUMBERS)
@example(key="place.zones", value={})  # no zones: the sort's zone check names it
def test_one_bad_value_names_its_key(key, value):
    result = _outcome(lambda: config_from_dict(_nest([(key, value)])))
    if isinstance(result, str):
        section, leaf = key.split(".")
        # The key itself, or (a cross-field check) the key it is checked against names it.
        assert f"'{section}." in result and leaf in result, result


def _toml_literal(value: object) -> str:
    """``value`` as an override's right-hand side, as a user would type it."""
    if isinstance(value, float):
        return {math.inf: "inf", -math.inf: "-inf"}.get(
            value, "nan" if value != value else repr(value)
        )
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return value
    if isinstance(value, int) and value.bit_length() > 14000:
        return "9" * 4400  # str() refuses ints this long
    if isinstance(value, list):
        return "[" + ", ".join(_toml_literal(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k!r} = {_toml_literal(v)}" for k, v in value.items()) + "}"
    return str(value)  # ints, None, dates


OVERRIDE_TEXT = st.one_of(
    st.builds(lambda k, v: f"{k}={_toml_literal(v)}", st.sampled_from(KEYS), VALUES | NUMBERS),
    st.builds(lambda k, v: f"{k}={v}", st.sampled_from(KEYS), st.text(max_size=12)),
    st.text(max_size=20),  # anything at all, '=' or not
    st.builds(lambda a, b: f"{a}.{b}", st.sampled_from(KEYS), st.text(max_size=8)),
)


@FAST
@given(st.lists(OVERRIDE_TEXT, min_size=1, max_size=4))
def test_generated_overrides_give_a_config_or_one_line_error(overrides):
    def load() -> Config:
        data: dict = {}
        for assignment in overrides:
            apply_override(data, assignment)
        return config_from_dict(data, "--set " + " ".join(overrides))

    _outcome(load)


@settings(deadline=None, max_examples=60)
@given(st.lists(OVERRIDE_TEXT, min_size=1, max_size=3))
def test_the_command_line_exits_0_or_2_with_one_line(overrides):
    argv = [part for text in overrides for part in ("--set", text)] + ["config"]
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        code = cli.main(argv)
    if code == 0:
        assert err.getvalue() == ""
    else:
        assert code == 2, err.getvalue()
        lines = err.getvalue().splitlines()
        assert len(lines) == 1 and lines[0].startswith("armvision: error: "), lines


@settings(deadline=None, max_examples=60, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.one_of(
        st.builds(
            lambda d: tomli_w.dumps(d).encode(),
            st.dictionaries(
                st.sampled_from(SECTIONS),
                st.dictionaries(
                    st.sampled_from([k.split(".")[1] for k in KEYS]) | st.text(max_size=6),
                    st.one_of(
                        st.booleans(),
                        st.integers(-(2**63), 2**63 - 1),
                        st.floats(),
                        st.text(max_size=8),
                        st.lists(st.floats(), max_size=4),
                    ),
                    max_size=4,
                ),
                max_size=3,
            ),
        ),
        st.binary(max_size=60),  # not UTF-8, not TOML
        st.text(max_size=60).map(str.encode),
    )
)
def test_generated_files_give_a_config_or_one_line_error(content):
    fd, path = tempfile.mkstemp(suffix=".toml")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(content)
        _outcome(lambda: load_config(path), names=os.path.basename(path))
    finally:
        os.unlink(path)


@FAST
@given(ASSIGNMENTS)
def test_every_valid_config_round_trips_through_toml(assignments):
    try:
        config = config_from_dict(_nest(assignments))
    except ConfigError:
        return
    data = __import__("armvision.config", fromlist=["tomllib"]).tomllib.loads(
        config_to_toml(config)
    )
    assert config_from_dict(data) == config
