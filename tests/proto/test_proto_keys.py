"""Zenoh key expressions: layout, validation, parsing."""

import pytest

from liquidtwin_proto import (ANY, IN_STREAMS, MAX_ID_LENGTH, OUT_STREAMS, Keys, ParsedKey,
                              validate_session_id)


def test_keys_follow_the_architecture_layout():
    k = Keys()
    assert k.stream_in("s1", "poses") == "liquidtwin/s1/in/poses"
    assert k.stream_out("s1", "particles") == "liquidtwin/s1/out/particles"
    assert k.rpc("create_session") == "liquidtwin/rpc/create_session"
    assert k.rpc("reset", session="s1") == "liquidtwin/s1/rpc/reset"
    assert k.alive("servers", "srv-0") == "liquidtwin/alive/servers/srv-0"
    assert k.alive("clients", "robot.a_1") == "liquidtwin/alive/clients/robot.a_1"
    assert [k.stream_in("s", s).rsplit("/", 1)[1] for s in IN_STREAMS] == \
        ["poses", "camera", "image", "mask"]
    assert [k.stream_out("s", s).rsplit("/", 1)[1] for s in OUT_STREAMS] == \
        ["particles", "volumes", "control", "overlay", "metrics"]


def test_configurable_prefix():
    k = Keys("lab-3/liquidtwin")
    assert k.stream_in("s", "image") == "lab-3/liquidtwin/s/in/image"
    assert k.parse("lab-3/liquidtwin/s/in/image") == ParsedKey("in", "image", session="s")


def test_wildcard_patterns():
    k = Keys()
    assert k.stream_in(ANY, ANY) == "liquidtwin/*/in/*"
    assert k.stream_out("s1", ANY) == "liquidtwin/s1/out/*"
    assert k.rpc(ANY) == "liquidtwin/rpc/*"
    assert k.rpc(ANY, session=ANY) == "liquidtwin/*/rpc/*"
    assert k.alive(ANY, ANY) == "liquidtwin/alive/*/*"


@pytest.mark.parametrize(
    "session, message",
    [
        ("a/b", "contains '/'"),
        ("a*", "contains '\\*'"),
        ("**", "contains '\\*'"),
        ("*", "contains '\\*'"),
        ("$*", "contains '\\$'"),
        ("a?b", "contains '\\?'"),
        ("a b", "only letters, digits"),
        ("é", "only letters, digits"),
        ("", "must not be empty"),
        ("x" * (MAX_ID_LENGTH + 1), f"{MAX_ID_LENGTH + 1} characters long"),
        ("rpc", "reserved"),
        ("alive", "reserved"),
    ],
)
def test_bad_session_ids_are_rejected_with_a_reason(session, message):
    with pytest.raises(ValueError, match=message):
        validate_session_id(session)
    if session != "*":  # ANY is the one wildcard builders accept on purpose
        with pytest.raises(ValueError, match=message):
            Keys().stream_in(session, "poses")


def test_longest_session_id_is_accepted():
    s = "x" * MAX_ID_LENGTH
    assert Keys().stream_out(s, "volumes").split("/")[1] == s


def test_non_string_session_id():
    with pytest.raises(TypeError, match="must be a str"):
        validate_session_id(3)


@pytest.mark.parametrize("prefix", ["", "/lt", "lt/", "a//b", "lt*", "lt/$x", "l t"])
def test_bad_prefixes(prefix):
    with pytest.raises(ValueError):
        Keys(prefix)


def test_unknown_streams_roles_and_methods():
    k = Keys()
    with pytest.raises(ValueError, match="unknown input stream 'particles'"):
        k.stream_in("s", "particles")
    with pytest.raises(ValueError, match="unknown output stream 'poses'"):
        k.stream_out("s", "poses")
    with pytest.raises(ValueError, match="liveliness role"):
        k.alive("robots", "x")
    with pytest.raises(ValueError, match="rpc method"):
        k.rpc("a/b")
    with pytest.raises(ValueError, match="node id"):
        k.alive("servers", "")


def test_parse_is_the_inverse_of_the_builders():
    k = Keys()
    cases = {
        k.stream_in("s1", "mask"): ParsedKey("in", "mask", session="s1"),
        k.stream_out("s1", "metrics"): ParsedKey("out", "metrics", session="s1"),
        k.rpc("status"): ParsedKey("rpc", "status"),
        k.rpc("set_task", session="s1"): ParsedKey("rpc", "set_task", session="s1"),
        k.alive("clients", "c7"): ParsedKey("alive", "c7", role="clients"),
    }
    for key, parsed in cases.items():
        assert k.parse(key) == parsed


@pytest.mark.parametrize(
    "key",
    ["other/s1/in/poses", "liquidtwin", "liquidtwin/s1/in/nope", "liquidtwin/s1/out/poses",
     "liquidtwin/s1/in", "liquidtwin/s1/in/poses/extra", "liquidtwin/rpc/s1/x/y",
     "liquidtwin/alive/robots/x", "liquidtwin/rpc/in/poses", "liquidtwin/s*/in/poses",
     "liquidtwin/s1/rpc/a$b", "liquidtwin/s1/side/x"],
)
def test_parse_rejects_foreign_keys(key):
    with pytest.raises(ValueError):
        Keys().parse(key)
