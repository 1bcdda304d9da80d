"""Headers as attachments, request parsing and error payloads (liquidtwin_proto.wire)."""

import pytest

import liquidtwin_proto as lt
from liquidtwin_proto import liquidtwin_pb2 as pb


def test_attachment_round_trip_and_version_check():
    header = lt.make_header("pour-01", seq=5, stamp_ns=123)
    again = lt.decode_attachment(lt.encode_attachment(header), "pour-01")
    assert again == header and again.version == lt.PROTOCOL_VERSION
    old = pb.Header(session_id="pour-01", seq=1, version=0)
    with pytest.raises(lt.WireError) as info:
        lt.decode_attachment(old.SerializeToString())
    assert info.value.code == pb.Error.UNSUPPORTED_VERSION
    assert "unsupported protocol version 0" in str(info.value)


@pytest.mark.parametrize("attachment,code", [
    (None, pb.Error.UNSUPPORTED_VERSION),
    (b"\xff\xff\xff", pb.Error.BAD_REQUEST),
    (b"\x0a" * 2000, pb.Error.TOO_LARGE),
])
def test_bad_attachments(attachment, code):
    with pytest.raises(lt.WireError) as info:
        lt.decode_attachment(attachment)
    assert info.value.code == code


def test_attachment_for_another_session_is_refused():
    header = lt.make_header("pour-02")
    with pytest.raises(lt.WireError, match="names session 'pour-02'"):
        lt.decode_attachment(lt.encode_attachment(header), "pour-01")


def test_parse_request_requires_a_current_header():
    good = pb.SessionRequest(header=lt.make_header("s1"))
    assert lt.parse_request(pb.SessionRequest, good.SerializeToString()) == good
    with pytest.raises(lt.WireError) as info:
        lt.parse_request(pb.SessionRequest, b"")
    assert info.value.code == pb.Error.UNSUPPORTED_VERSION
    with pytest.raises(lt.WireError) as info:
        lt.parse_request(pb.SessionRequest, good.SerializeToString(), max_bytes=4)
    assert info.value.code == pb.Error.TOO_LARGE


def test_error_payload_round_trip():
    payload = lt.error_bytes(pb.Error.UNKNOWN_SESSION, "no session 'x'", lt.make_header("x"))
    err = lt.parse_error(payload)
    assert err.code == pb.Error.UNKNOWN_SESSION and err.message == "no session 'x'"
    assert lt.error_name(err.code) == "UNKNOWN_SESSION"
    assert lt.parse_error(b"\xff\xff").code == pb.Error.INTERNAL
