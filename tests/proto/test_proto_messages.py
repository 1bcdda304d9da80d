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


def _spec() -> pb.SceneSpec:
    return pb.SceneSpec(
        header=_header(0), name="pour_partial", objects=[_object()],
        fills=[pb.Fill(container="cup", fraction=0.6)],
        simulation=pb.SimulationSettings(h=0.011, dt=1 / 120, iterations=4, spacing=0.006),
        motion="pour", motion_params={"tilt_deg": 95.0}, duration_s=6.0, cameras=["cam0"],
    )


def _session_spec() -> pb.SessionSpec:
    return pb.SessionSpec(
        scene=_spec(), cameras=[_camera()],
        fluid=pb.FluidParameters(lambda_c=0.1, lambda_v=60.0, lambda_s=0.0, lambda_omega=1.0,
                                 relaxation=4.0),
        tracking=pb.WARP_FIELD, device="cpu", correction_gain=0.5, mask_source="rgb",
        pose_filter=_pose_filter())


def _pose_filter() -> pb.PoseFilter:
    return pb.PoseFilter(position_noise_m=5e-4, rotation_noise_rad=0.005, acceleration_m_s2=2.0,
                         angular_acceleration_rad_s2=10.0)


def _camera() -> pb.CameraSetup:
    return pb.CameraSetup(name="cam0", width=640, height=480, k=[500, 0, 320, 0, 500, 240, 0, 0, 1],
                          d=[0.01, 0, 0, 0, 0], pose=[0, 0.5, 0.5, 1, 0, 0, 0])


def _task() -> pb.Task:
    return pb.Task(pour=pb.Task.PourToVolume(source="cup", target="bowl", volume_ml=150.0,
                                             max_angle_rad=2.0, max_rate_rad_s=0.5),
                   controller="pid")


def _status() -> pb.SessionStatus:
    return pb.SessionStatus(
        header=_header(3), session_id="pour-01", state="running", spec=_session_spec(),
        sim_time_s=1.5, frames_done=45, particles=4096,
        volumes=[pb.ContainerVolume(name="cup", ml=120.0)], task=_task(),
        log_path="/var/liquidtwin/pour-01/log.mcap", checkpoint_path="/var/liquidtwin/pour-01/ckpt.pt",
        restored=True, server_id="srv-1",
        model_json='{"version": 1, "name": "drag", "params": {"c": 2.0}, "base": {}}')


def _overlay() -> pb.OverlayInfo:
    return pb.OverlayInfo(camera="cam0", observed_only_rgb=0x0000FF, model_only_rgb=0xFF0000,
                          overlap_rgb=0x00FF00, observed_px=100, model_px=90, overlap_px=80)


def _mesh() -> pb.ObjectMesh:
    return pb.ObjectMesh(name="cup",
                         vertices=pb.PackedArray(shape=[3, 3], dtype="float32", data=bytes(36)),
                         faces=pb.PackedArray(shape=[1, 3], dtype="uint32", data=bytes(12)),
                         container=True)


SAMPLES = {
    "Header": _header(),
    "PackedArray": pb.PackedArray(shape=[2, 3], dtype="float32", data=bytes(range(24))),
    "Error": pb.Error(header=_header(), code=pb.Error.UNKNOWN_SESSION,
                      message="no session 'pour-02' on this server"),
    "ContainerVolume": pb.ContainerVolume(name="source", ml=212.5, mask_ml=205.0),
    "Volumes": pb.Volumes(
        header=_header(8),
        containers=[pb.ContainerVolume(name="source", ml=150.0),
                    pb.ContainerVolume(name="target", ml=62.5)],
    ),
    "SceneObject": _object(),
    "Fill": pb.Fill(container="cup", volume_ml=150.0),
    "SimulationSettings": pb.SimulationSettings(h=0.011, dt=1 / 120, iterations=4, spacing=0.006,
                                                reference_iterations=4, max_correction_spacings=0.5,
                                                cut_wall_pairs=True),
    "SceneSpec": _spec(),
    "FluidParameters": pb.FluidParameters(lambda_c=0.1, lambda_v=60.0, lambda_s=0.01,
                                          lambda_omega=1.0, relaxation=4.0),
    "CameraSetup": _camera(),
    "SessionSpec": _session_spec(),
    "PoseFilter": _pose_filter(),
    "Task": _task(),
    "Control": pb.Control(header=_header(9), object="cup", tilt_angle_rad=1.2, tilt_rate_rad_s=0.3,
                          achieved_ml=40.0, remaining_ml=110.0, done=True, controller="pid",
                          axis_point_m=[0.03, 0.18, 0.0], axis_direction=[0.0, 0.0, 1.0],
                          pose=[0.0, 0.2, 0.0, 0.0, 0.0, 0.0998, 0.995], linear_velocity_m_s=[0.0, 0.0, 0.0],
                          angular_velocity_rad_s=[0.0, 0.0, 0.3]),
    "OverlayInfo": _overlay(),
    "Metrics": pb.Metrics(header=_header(10), input_seq=9, sim_time_s=0.3, iou=0.8, step_ms=12.0,
                          correction_ms=3.0, lag_ms=20.0, sim_lag_s=0.01, particles=4096, steps=4,
                          frames_in=10, frames_done=9, dropped_stale=1, dropped_out_of_order=2,
                          rejected=3, overlay=_overlay()),
    "SessionStatus": _status(),
    "CreateSessionRequest": pb.CreateSessionRequest(header=_header(0), session_id="pour-01",
                                                    spec=_session_spec(), client_id="robot-7"),
    "ListSessionsRequest": pb.ListSessionsRequest(header=_header(0)),
    "ListSessionsReply": pb.ListSessionsReply(header=_header(1), server_id="srv-1",
                                              sessions=[_status()]),
    "SessionRequest": pb.SessionRequest(header=_header(2)),
    "SetTaskRequest": pb.SetTaskRequest(header=_header(4), task=_task()),
    "ObjectMesh": _mesh(),
    "SceneMeshes": pb.SceneMeshes(header=_header(5), objects=[_mesh()]),
    "Hypothesis": pb.Hypothesis(name="60%", probability=0.93, log_likelihood=-12.5),
    "InferFillRequest": pb.InferFillRequest(header=_header(8), session_id="s1", container="source",
                                            fractions=[0.0, 0.3, 0.6, 0.9], tracking=pb.WARP_FIELD),
    "InferBlockageRequest": pb.InferBlockageRequest(header=_header(9), session_id="s1", object="pipe",
                                                    tracking=pb.OPEN_LOOP),
    "InferenceReply": pb.InferenceReply(
        header=_header(10), session_id="s1", hypotheses=[pb.Hypothesis(name="none", probability=1.0,
                                                                       log_likelihood=-3.0)],
        best="none", times_s=[0.1, 0.2], frames=2, wall_s=1.5,
        probability_over_time=pb.PackedArray(shape=[2, 1], dtype="float64", data=bytes(16))),
    "DiscrepancyRequest": pb.DiscrepancyRequest(header=_header(11), session_id="s1", camera="cam0",
                                                candidates=["drag", "time_offset"], null_runs=1, calibrate=True),
    "DiscrepancyReply": pb.DiscrepancyReply(header=_header(12), session_id="s1", decision="drag",
                                            report_json='{"decision": "drag"}',
                                            model_json='{"version": 1, "name": "drag", "params": {"c": 2.0}}'),
    "LoadModelRequest": pb.LoadModelRequest(header=_header(13), session_id="s1",
                                            model_json='{"version": 1, "name": "none"}'),
}


@pytest.mark.parametrize("field", ["lambda_c", "lambda_v", "lambda_s", "lambda_omega", "relaxation"])
def test_fluid_parameters_tell_zero_from_unset(field):
    """A fluid parameter of 0 (e.g. no surface tension) differs from "use the default"."""
    zero = pb.FluidParameters(**{field: 0.0})
    again = pb.FluidParameters.FromString(zero.SerializeToString())
    assert again.HasField(field) and not pb.FluidParameters().HasField(field)


def test_every_message_has_a_sample():
    assert set(SAMPLES) == set(pb.DESCRIPTOR.message_types_by_name)


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_sample_sets_every_field(name):
    message = SAMPLES[name]
    unset = [f.name for f in message.DESCRIPTOR.fields if not _is_set(message, f)]
    assert unset == []


@pytest.mark.parametrize("task", [
    pb.Task(catch_stream=pb.Task.CatchStream(source="jug", catcher="cup", max_speed_m_s=0.4, range_m=0.2),
            controller="mpc"),
    pb.Task(send=pb.Task.SendToContainer(object="plate", target="bowl3", max_angle_rad=0.6, max_rate_rad_s=2.0),
            controller="mpc"),
])
def test_the_other_task_kinds_set_every_field_and_round_trip(task):
    kind = getattr(task, task.WhichOneof("kind"))
    assert [f.name for f in kind.DESCRIPTOR.fields if not _is_set(kind, f)] == []
    assert pb.Task.FromString(task.SerializeToString()) == task


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
