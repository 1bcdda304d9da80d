"""Every liquidtwin message round-trips through its wire form with all fields set."""

import pytest
from google.protobuf.descriptor import FieldDescriptor

import liquidtwin_proto as lt
from liquidtwin_proto import liquidtwin_pb2 as pb


def _header(seq: int = 7) -> pb.Header:
    return pb.Header(session_id="pour-01", seq=seq, stamp_ns=1_700_000_000_123_456_789,
                     version=lt.PROTOCOL_VERSION)


def _object() -> pb.SceneObject:
    return pb.SceneObject(name="cup", model="mesh", params={"scale": 1.0}, mesh_uri="meshes/cup.stl",
                          mesh_sha256="ab" * 32, initial_pose=[0, 0.2, 0, 0, 0, 0, 1], container=True)


SAMPLES = {
    "Header": _header(),
    "PackedArray": pb.PackedArray(shape=[2, 3], dtype="float32", data=bytes(range(24))),
    "Error": pb.Error(header=_header(), code=pb.Error.UNKNOWN_SESSION,
                      message="no session 'pour-02' on this server"),
    "ContainerVolume": pb.ContainerVolume(name="source", ml=212.5),
    "Volumes": pb.Volumes(
        header=_header(8),
        containers=[pb.ContainerVolume(name="source", ml=150.0),
                    pb.ContainerVolume(name="target", ml=62.5)],
    ),
    "SceneObject": _object(),
    "Fill": pb.Fill(container="cup", volume_ml=150.0),
    "SimulationSettings": pb.SimulationSettings(h=0.011, dt=1 / 120, iterations=4, spacing=0.006),
    "SceneSpec": pb.SceneSpec(
        header=_header(0), name="pour_partial", objects=[_object()],
        fills=[pb.Fill(container="cup", fraction=0.6)],
        simulation=pb.SimulationSettings(h=0.011, dt=1 / 120, iterations=4, spacing=0.006),
        motion="pour", motion_params={"tilt_deg": 95.0}, duration_s=6.0, cameras=["cam0"],
    ),
}


def test_every_message_has_a_sample():
    assert set(SAMPLES) == set(pb.DESCRIPTOR.message_types_by_name)


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_sample_sets_every_field(name):
    message = SAMPLES[name]
    unset = [f.name for f in message.DESCRIPTOR.fields if not _is_set(message, f)]
    assert unset == []


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_round_trip(name):
    message = SAMPLES[name]
    wire = message.SerializeToString()
    again = type(message).FromString(wire)
    assert again == message
    assert again.SerializeToString() == wire


def test_package_is_liquidtwin_v1():
    assert pb.DESCRIPTOR.package == "liquidtwin.v1"
    assert lt.Header.DESCRIPTOR.full_name == "liquidtwin.v1.Header"


def test_protocol_version_is_current_enum_value():
    assert lt.PROTOCOL_VERSION == pb.PROTOCOL_VERSION_CURRENT == 1
    assert lt.ProtocolVersion.Name(0) == "PROTOCOL_VERSION_UNSPECIFIED"


def test_error_codes():
    names = {v.name for v in pb.Error.Code.DESCRIPTOR.values}
    assert {"BAD_REQUEST", "UNKNOWN_SESSION", "UNSUPPORTED_VERSION", "TOO_LARGE",
            "NON_FINITE", "INTERNAL"} <= names
    assert pb.Error.Code.Name(0) == "CODE_UNSPECIFIED"


def test_public_names_resolve():
    for name in lt.__all__:
        assert getattr(lt, name) is not None, name


def _is_set(message, field) -> bool:
    oneof = field.containing_oneof
    if oneof is not None:  # members of a oneof exclude each other: one set is enough
        return message.WhichOneof(oneof.name) is not None
    if field.is_repeated:
        return len(getattr(message, field.name)) > 0
    if field.type == FieldDescriptor.TYPE_MESSAGE:
        return message.HasField(field.name)
    return getattr(message, field.name) != field.default_value
