"""ROS 2 over rmw_zenoh: the wire format as rmw_zenoh's docs/design.md writes it, checked against
independent encoders (rosbags, Foxglove's mcap-ros2-support from .msg text)
and an independent ROS 2-over-Zenoh client (zenoh-ros2-sdk), all on real Zenoh over loopback."""

from __future__ import annotations

import math
import struct
import subprocess
import sys
import time

import numpy as np
import pytest
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
from rosbags.typesys import Stores, get_typestore

from agent.core.params import EPUCK
from hardware.config import HardwareConfigError
from hardware.ros2 import (
    COLOR_RGBA,
    POSE_STAMPED,
    TWIST,
    Ros2Backend,
    Ros2BackendConfig,
    Ros2Messages,
    Ros2PosesConfig,
    Ros2PoseSource,
)
from sim.emulators.mocap import MocapEmulator, circle
from sim.node.hardware import TwistDrive
from tests.conftest import REPO, wait_for
from transport.rmw_zenoh import (
    Attachment,
    NodeName,
    RosNode,
    entity_token,
    gid_of,
    node_token,
    topic_key,
)
from transport.session import client_of, loopback_router, open_session

TWIST_HASH = "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"  # design.md's chatter
JAZZY = get_typestore(Stores.ROS2_JAZZY)

# The ROS 2 message definitions (Jazzy's .msg files without comments), written out for the
# independent decoders: nothing here comes from rosbags.
MSG = {
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "std_msgs/msg/ColorRGBA": "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n",
    "geometry_msgs/msg/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Twist": "Vector3 linear\nVector3 angular\n",
    "geometry_msgs/msg/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/msg/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/msg/PoseStamped": "std_msgs/Header header\nPose pose\n",
}
DEPENDENCIES = {
    TWIST: ["geometry_msgs/msg/Vector3"],
    COLOR_RGBA: [],
    POSE_STAMPED: [
        "std_msgs/msg/Header",
        "builtin_interfaces/msg/Time",
        "geometry_msgs/msg/Pose",
        "geometry_msgs/msg/Point",
        "geometry_msgs/msg/Quaternion",
    ],
}


def foxglove_decode(ros_type: str, cdr: bytes):
    """Decode CDR with mcap-ros2-support from the concatenated .msg text (the ros2msg schema format)."""
    text = MSG[ros_type]
    for dep in DEPENDENCIES[ros_type]:
        text += "=" * 80 + f"\nMSG: {dep.replace('/msg/', '/')}\n" + MSG[dep]
    schema = Schema(id=1, name=ros_type, encoding="ros2msg", data=text.encode())
    return DecoderFactory().decoder_for("cdr", schema)(cdr)


@pytest.fixture
def router():
    settings = loopback_router()
    with open_session(settings):
        yield settings


def raw_session(router):
    """A plain zenoh session: the independent observer of what went on the wire (subscriptions on it
    queue samples in zenoh's default FIFO, read with try_recv)."""
    return open_session(client_of(router))


def drain(handler, timeout: float = 5.0, at_least: int = 1) -> list:
    samples: list = []
    end = time.monotonic() + timeout
    while time.monotonic() < end and len(samples) < at_least:
        sample = handler.try_recv()
        if sample is None:
            time.sleep(0.01)
        else:
            samples.append(sample)
    return samples


# --- the documented format, written out ----------------------------------------------------------


def test_topic_keys_are_rmw_zenohs():
    assert (
        topic_key(0, "/robot1/cmd_vel", TWIST, TWIST_HASH)
        == "0/robot1/cmd_vel/geometry_msgs::msg::dds_::Twist_/RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a"
    )
    # design.md's examples: the chatter topic, plain and under the /robot1 namespace
    assert topic_key(0, "/chatter", "std_msgs/msg/String", STRING_HASH) == (
        "0/chatter/std_msgs::msg::dds_::String_/" + STRING_HASH
    )
    assert topic_key(0, "/robot1/chatter", "std_msgs/msg/String", STRING_HASH) == (
        "0/robot1/chatter/std_msgs::msg::dds_::String_/" + STRING_HASH
    )
    assert topic_key(0, "/robot1/cmd_vel", TWIST, "TypeHashNotSupported").endswith("Twist_/TypeHashNotSupported")


def test_rosbags_type_hashes_are_the_documented_ones():
    assert JAZZY.hash_rihs01("std_msgs/msg/String") == STRING_HASH
    assert Ros2Messages("jazzy").type_hash(TWIST) == TWIST_HASH
    assert Ros2Messages("humble").type_hash(TWIST) == "TypeHashNotSupported"


def test_liveliness_tokens_are_rmw_zenohs():
    # design.md's listener and talker of demo_nodes_cpp, verbatim
    zid = "aac3178e146ba6f1fc6e6a4085e77f21"
    listener = NodeName(2, zid, 0, "/", "listener")
    assert node_token(listener) == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    assert entity_token(listener, 10, "MS", "/chatter", "std_msgs/msg/String", STRING_HASH) == (
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/std_msgs::msg::dds_::String_/"
        + STRING_HASH
        + "/::,10:,:,:,,"
    )
    talker_node = NodeName(2, "8b20917502ee955ac4476e0266340d5c", 0, "/", "talker")
    talker = entity_token(talker_node, 10, "MP", "/chatter", "std_msgs/msg/String", STRING_HASH, qos="::,7:,:,:,,")
    assert talker == (
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
        + STRING_HASH
        + "/::,7:,:,:,,"
    )
    # a namespace's slashes become '%' too
    assert node_token(NodeName(0, zid, 3, "/lab/arena", "cam")) == f"@ros2_lv/0/{zid}/3/3/NN/%/%lab%arena/cam"


def test_attachment_is_seq_stamp_length_gid_little_endian():
    gid = bytes(range(16))
    data = Attachment(7, 1_700_000_000_123_456_789, gid).encode()
    written_out = (7).to_bytes(8, "little") + (1_700_000_000_123_456_789).to_bytes(8, "little") + b"\x10" + gid
    assert data == written_out
    assert Attachment.decode(data) == Attachment(7, 1_700_000_000_123_456_789, gid)
    with pytest.raises(ValueError):
        Attachment.decode(data[:-1])
    with pytest.raises(ValueError):
        Attachment.decode(data[:16] + b"\x08" + gid)


# --- what the backend puts on the wire -----------------------------------------------------------


def test_backend_puts_twist_and_color_as_rmw_zenoh_does(router):
    config = Ros2BackendConfig(namespaces=["robot0", "robot1"])
    with raw_session(router) as observer, Ros2Backend(config, client_of(router)) as backend:
        wire = observer.declare_subscriber("0/robot1/**")
        time.sleep(0.2)  # let the subscription reach the router
        before = time.time_ns()
        backend.set_commands([1], [0.25], [-0.75], [[255, 128, 0]])
        after = time.time_ns()
        samples = {str(s.key_expr): s for s in drain(wire, at_least=2)}
        twist_key = "0/robot1/cmd_vel/geometry_msgs::msg::dds_::Twist_/" + TWIST_HASH
        color_key = "0/robot1/led/std_msgs::msg::dds_::ColorRGBA_/" + JAZZY.hash_rihs01(COLOR_RGBA)
        assert set(samples) == {twist_key, color_key}

        twist = samples[twist_key]
        assert str(twist.encoding) == "application/cdr"
        seq, stamp, gid_length, gid = struct.unpack("<qqB16s", twist.attachment.to_bytes())
        # entity ids count up in the order of declaration: cmd_vel of robot 0, 1, then led of robot 0, 1
        node = NodeName(0, backend.node.zid, 0, "/", "pixelswarm_backend")
        token = entity_token(node, 2, "MP", "/robot1/cmd_vel", TWIST, TWIST_HASH)
        assert (seq, gid_length, gid) == (1, 16, gid_of(token))
        assert before <= stamp <= after
        cdr = twist.payload.to_bytes()
        assert cdr[:4] == b"\x00\x01\x00\x00" and len(cdr) == 52  # CDR little-endian header; 6 float64
        decoded = foxglove_decode(TWIST, cdr)
        assert (decoded.linear.x, decoded.angular.z) == (0.25, -0.75)
        assert (decoded.linear.y, decoded.angular.x) == (0.0, 0.0)
        assert JAZZY.deserialize_cdr(cdr, TWIST).angular.z == -0.75

        color = foxglove_decode(COLOR_RGBA, samples[color_key].payload.to_bytes())
        assert (color.r, color.g, color.b, color.a) == pytest.approx((1.0, 128 / 255, 0.0, 1.0), abs=1e-6)

        # the graph: one node token, an MP token per topic, exactly as design.md spells them
        tokens = {str(r.ok.key_expr) for r in observer.liveliness().get("@ros2_lv/0/**") if r.ok is not None}
        zid = backend.node.zid
        assert node_token(NodeName(0, zid, 0, "/", "pixelswarm_backend")) in tokens
        assert token in tokens
        assert (
            f"@ros2_lv/0/{zid}/0/4/MP/%/%/pixelswarm_backend/%robot1%led/std_msgs::msg::dds_::ColorRGBA_/"
            + JAZZY.hash_rihs01(COLOR_RGBA)
            + "/::,10:,:,:,,"
        ) in tokens
        assert len(tokens) == 5
    # closing leaves the ROS graph
    with raw_session(router) as observer:
        assert [r for r in observer.liveliness().get("@ros2_lv/0/**") if r.ok is not None] == []


def test_watchdog_sends_a_zero_twist_to_a_silent_robot(router):
    config = Ros2BackendConfig(namespaces=["robot0"], watchdog=0.2)
    with raw_session(router) as observer, Ros2Backend(config, client_of(router)) as backend:
        wire = observer.declare_subscriber("0/robot0/cmd_vel/**")
        time.sleep(0.2)
        backend.set_commands([0], [0.3], [0.1])
        first, second = drain(wire, at_least=2)
        assert JAZZY.deserialize_cdr(first.payload.to_bytes(), TWIST).linear.x == 0.3
        stop = foxglove_decode(TWIST, second.payload.to_bytes())
        assert (stop.linear.x, stop.angular.z) == (0.0, 0.0)
        assert wait_for(lambda: backend.stats()["watchdog_stops"] == 1, timeout=2)
        # no repeat while the robot stays stopped
        assert drain(wire, timeout=0.5) == []
        assert backend.stats()["moving"] == 0


def test_pixelswarm_stop_sends_every_robot_a_zero_twist(router, tmp_path):
    hw = tmp_path / "ros2.toml"
    hw.write_text('[backend]\nkind = "ros2"\nnamespaces = ["robot0", "robot1"]\n')
    with raw_session(router) as observer:
        wire = observer.declare_subscriber("0/*/cmd_vel/**")
        time.sleep(0.2)  # let the subscription reach the router
        endpoint = client_of(router).connect[0]
        result = subprocess.run(
            [sys.executable, "-m", "sim.cli", "stop", "--hardware", str(hw), "-e", endpoint],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=REPO,
        )
        assert result.returncode == 0, result.stderr
        samples = drain(wire, at_least=2)
    assert {str(s.key_expr).split("/")[1] for s in samples} == {"robot0", "robot1"}
    for s in samples:
        stop = foxglove_decode(TWIST, s.payload.to_bytes())
        assert (stop.linear.x, stop.linear.y, stop.angular.z) == (0.0, 0.0, 0.0)


def test_pixelswarm_stop_names_the_robots_whose_stop_nobody_heard(router, tmp_path):
    """A put has no answer: a robot whose cmd_vel has no subscriber (its driver down, a wrong namespace)
    is not reported stopped."""
    hw = tmp_path / "ros2.toml"
    hw.write_text('[backend]\nkind = "ros2"\nnamespaces = ["robot0", "robot1"]\n')
    with raw_session(router) as session, session.declare_subscriber("0/robot0/cmd_vel/**"):  # robot 0's driver only
        time.sleep(0.2)  # let the subscription reach the router
        result = subprocess.run(
            [sys.executable, "-m", "sim.cli", "stop", "--hardware", str(hw), "-e", client_of(router).connect[0]],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=REPO,
        )
    assert result.returncode == 1
    assert result.stderr.strip().splitlines() == ["pixelswarm stop: error: robots 1 were not reached"]


def test_a_robot_is_reached_once_a_driver_subscribes_to_its_cmd_vel(router):
    """What the hardware node waits for at start-up: a put has no answer, so a ROS 2 robot counts as
    reached when a subscription on its cmd_vel is known (a robot whose driver is down was taken as
    reached, and the run started without it)."""
    config = Ros2BackendConfig(namespaces=["robot0", "robot1"])
    drive = TwistDrive(config, client_of(router), EPUCK)
    with raw_session(router) as session, drive.backend:
        drive.start()
        assert drive.unreached() == [0, 1]
        assert drive.why_unreached(1) == "nobody subscribes to /robot1/cmd_vel"
        with session.declare_subscriber("0/robot1/cmd_vel/**"):  # robot 1's driver comes up
            assert wait_for(lambda: drive.unreached() == [0], timeout=5)


def test_bad_commands_are_refused_whole(router):
    backend = Ros2Backend(Ros2BackendConfig(namespaces=["robot0", "robot1"]), client_of(router))
    with pytest.raises(RuntimeError):
        backend.set_commands([0], [0.1], [0.0])  # not started
    with raw_session(router) as observer, backend:
        wire = observer.declare_subscriber("0/**")
        time.sleep(0.2)
        for bad in (
            ([0, 2], [0.1, 0.1], [0.0, 0.0], None),  # no robot 2
            ([0, 1], [0.1, math.nan], [0.0, 0.0], None),
            ([0, 1], [0.1, 0.1], [0.0], None),
            ([0, 1], [0.1, 0.1], [0.0, 0.0], [[255, 0, 0]]),  # one colour for two robots
        ):
            with pytest.raises(ValueError):
                backend.set_commands(*bad)
        assert drain(wire, timeout=0.5) == []  # nothing went out, not even for robot 0
        assert backend.stats()["commands"] == 0


# --- an independent ROS 2-over-Zenoh client, both directions -------------------------------------


@pytest.fixture
def ros2_sdk(router, tmp_path, monkeypatch):
    """zenoh-ros2-sdk as a ROS 2 peer of the router, reading .msg files from tmp_path only."""
    from zenoh_ros2_sdk import ZenohSession, message_registry

    def no_fetch(*args, **kwargs):
        raise RuntimeError("zenoh-ros2-sdk tried to fetch message definitions")

    monkeypatch.setattr(message_registry, "get_message_file_path", no_fetch)
    monkeypatch.setattr(message_registry, "clone_to_cache", no_fetch)
    for name, text in MSG.items():
        path = tmp_path / "msgs" / f"{name}.msg"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    monkeypatch.setattr(message_registry, "_registry", message_registry.MessageRegistry(str(tmp_path / "msgs")))
    monkeypatch.setenv("ZENOH_CONFIG_OVERRIDE", 'listen/endpoints=["tcp/127.0.0.1:0"]')
    port = int(router.listen[0].rsplit(":", 1)[1])
    session = ZenohSession.get_instance("127.0.0.1", port)
    yield port, session
    session.close()


def test_round_trip_with_zenoh_ros2_sdk(router, ros2_sdk):
    from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber, get_topic_info

    port, sdk = ros2_sdk
    twists: list = []
    sub = ROS2Subscriber("/robot0/cmd_vel", TWIST, twists.append, router_port=port)  # hashes the .msg itself
    pub = ROS2Publisher("/robot2/pose", POSE_STAMPED, router_port=port)
    poses = Ros2PoseSource(Ros2PosesConfig(), client_of(router))
    try:
        with Ros2Backend(Ros2BackendConfig(namespaces=["robot0"]), client_of(router)) as backend, poses:
            info = get_topic_info("/robot0/cmd_vel", domain_id=0, router_port=port, verbose=True)
            assert info is not None and info.topic_types == [TWIST] and info.publisher_count == 1
            assert info.publishers[0].node_name == "pixelswarm_backend"
            time.sleep(0.2)
            # pixelswarm -> SDK
            backend.set_commands([0], [0.5], [1.25])
            assert wait_for(lambda: twists, timeout=5)
            assert (twists[0].linear.x, twists[0].angular.z) == (0.5, 1.25)
            # SDK -> pixelswarm
            t = sdk.store.types
            yaw = 2.0
            pub.publish(
                header=t["std_msgs/msg/Header"](
                    stamp=t["builtin_interfaces/msg/Time"](sec=12, nanosec=500_000_000), frame_id="world"
                ),
                pose=t["geometry_msgs/msg/Pose"](
                    position=t["geometry_msgs/msg/Point"](x=1.5, y=-0.25, z=0.0),
                    orientation=t["geometry_msgs/msg/Quaternion"](
                        x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
                    ),
                ),
            )
            latest = wait_for(lambda: poses.latest(), timeout=5)
            assert list(latest) == [2]
            x, y, theta, stamp, age = latest[2]
            assert (x, y, stamp) == (1.5, -0.25, 12.5)
            assert theta == pytest.approx(yaw, abs=1e-12)
            assert age >= 0
            assert poses.stats()["without_attachment"] == 0  # the SDK's attachment reads as rmw_zenoh's
    finally:
        pub.close()
        sub.close()


# --- motion capture ------------------------------------------------------------------------------


def test_mocap_emulator_poses_arrive_with_their_yaw(router):
    truth = np.array([[1.0, 2.0, 3.0], [0.5, -0.5, -2.5], [-1.25, 0.0, 0.4]])  # yaw near +-pi too
    with Ros2PoseSource(Ros2PosesConfig(), client_of(router)) as source, raw_session(router) as observer:
        wire = observer.declare_subscriber("0/robot1/pose/**")
        time.sleep(0.2)
        with MocapEmulator(lambda t: truth, client_of(router), rate=50.0) as mocap:
            latest = wait_for(lambda: (p := source.latest()) and len(p) == 3 and p, timeout=5)
            ticks = source.ticks()
            resampled = [next(ticks) for _ in range(3)]
        assert mocap.error is None and mocap.published >= 3
        sample = drain(wire)[0]
    # what the emulator sent, read by Foxglove's decoder from the .msg text
    assert str(sample.key_expr) == "0/robot1/pose/geometry_msgs::msg::dds_::PoseStamped_/" + JAZZY.hash_rihs01(
        POSE_STAMPED
    )
    sent = foxglove_decode(POSE_STAMPED, sample.payload.to_bytes())
    assert sent.header.frame_id == "world"
    assert (sent.pose.position.x, sent.pose.position.y, sent.pose.position.z) == (0.5, -0.5, 0.0)
    q = sent.pose.orientation
    assert (q.x, q.y, q.z, q.w) == pytest.approx((0.0, 0.0, math.sin(-1.25), math.cos(-1.25)), abs=1e-12)
    now = time.time()
    for robot, (x, y, theta) in enumerate(truth):
        got = latest[robot]
        assert (got.x, got.y) == (x, y)
        assert got.theta == pytest.approx(theta, abs=1e-9)
        assert now - 5 < got.stamp <= now
    assert all(set(tick) == {0, 1, 2} for tick in resampled)
    assert resampled[-1][0].stamp >= resampled[0][0].stamp


def test_humble_keys_and_any_domain_are_accepted(router):
    messages = Ros2Messages()
    with (
        Ros2PoseSource(Ros2PosesConfig(), client_of(router)) as any_domain,
        Ros2PoseSource(Ros2PosesConfig(domain=0), client_of(router)) as domain0,
        raw_session(router) as talker,
    ):
        time.sleep(0.2)
        humble = "0/robot5/pose/geometry_msgs::msg::dds_::PoseStamped_/TypeHashNotSupported"
        talker.put(humble, messages.pose_stamped(0.1, 0.2, -1.0, 3.0), encoding="application/cdr")
        node = RosNode(talker, "mocap", domain=7)
        node.publisher("/robot6/pose", POSE_STAMPED, messages.type_hash(POSE_STAMPED)).publish(
            messages.pose_stamped(0.3, 0.4, 1.0, 4.0)
        )
        latest = wait_for(lambda: (p := any_domain.latest()) and len(p) == 2 and p, timeout=5)
        assert latest[5][:4] == pytest.approx((0.1, 0.2, -1.0, 3.0))
        assert latest[6][:4] == pytest.approx((0.3, 0.4, 1.0, 4.0))
        assert any_domain.stats()["without_attachment"] == 1  # a bare put is still a pose
        assert list(wait_for(lambda: domain0.latest(), timeout=5)) == [5]  # domain 7 is not domain 0
        node.close()


def test_a_robot_whose_pose_two_publishers_send_is_not_tracked_until_one_is_silent(router):
    """A second publisher on a robot's pose topic (a forger, or a second tracker) cannot be told from its
    tracker: while both are heard the robot has no pose, so its drive stops it as for a lost one; half a
    second after the other is silent the one left is taken. A publisher whose gid is copied shows it by
    its sequence numbers going back."""
    messages, pose_hash = Ros2Messages(), Ros2Messages().type_hash(POSE_STAMPED)
    with Ros2PoseSource(Ros2PosesConfig(), client_of(router)) as source, raw_session(router) as talker:
        tracker = RosNode(talker, "mocap").publisher("/robot2/pose", POSE_STAMPED, pose_hash)
        forger = RosNode(talker, "forger", node_id=50).publisher("/robot2/pose", POSE_STAMPED, pose_hash)
        time.sleep(0.3)  # the subscription reaches the router
        tracker.publish(messages.pose_stamped(1.0, 0.0, 0.0, time.time()))
        assert wait_for(lambda: (p := source.latest().get(2)) is not None and p.x == 1.0, timeout=5)
        # the forger's poses stamped ahead, beside which the true ones would look old: neither is taken
        assert wait_for(
            lambda: (
                forger.publish(messages.pose_stamped(5.0, 0.0, 0.0, time.time() + 0.9))
                and tracker.publish(messages.pose_stamped(1.0, 0.0, 0.0, time.time()))
                and 2 not in source.latest()
            ),
            timeout=5,
            interval=0.02,
        )
        assert source.robot_stats(2)["two_sources"] >= 1 and source.stats()["future"] == 0
        # the forger silent: the tracker's next poses are taken once RESTART_AFTER has passed
        assert wait_for(
            lambda: (
                tracker.publish(messages.pose_stamped(1.5, 0.0, 0.0, time.time()))
                and (p := source.latest().get(2)) is not None
                and p.x == 1.5
            ),
            timeout=5,
            interval=0.05,
        )
        # its gid copied by another publisher, whose count starts again
        copier = RosNode(talker, "copier", node_id=90).publisher("/robot2/pose", POSE_STAMPED, pose_hash)
        copier.gid = tracker.gid
        copier.publish(messages.pose_stamped(9.0, 0.0, 0.0, time.time()))
        tracker.publish(messages.pose_stamped(1.6, 0.0, 0.0, time.time()))
        clashes = source.robot_stats(2)["two_sources"]
        assert wait_for(lambda: 2 not in source.latest(), timeout=5)
        assert source.robot_stats(2)["two_sources"] > clashes
        assert source.stats()["two_sources"] == source.robot_stats(2)["two_sources"]


def test_undecodable_or_lost_pose_is_counted_not_raised(router):
    key = "0/robot1/pose/geometry_msgs::msg::dds_::PoseStamped_/TypeHashNotSupported"
    with Ros2PoseSource(Ros2PosesConfig(), client_of(router)) as source, raw_session(router) as talker:
        time.sleep(0.2)
        talker.put(key, b"\x00\x01\x00\x00\x01")  # truncated
        talker.put(key, Ros2Messages().pose_stamped(math.nan, 0.0, 0.0, 1.0))  # a body the cameras lost
        assert wait_for(lambda: source.latest() == {} and source.stats()["undecodable"] == 2, timeout=5)


# --- configuration -------------------------------------------------------------------------------


def test_config_defaults_and_robot_ids():
    backend = Ros2BackendConfig.from_table(
        {"kind": "ros2", "namespaces": ["robot0", "/lab/robot1"]}, "robots.toml [backend]"
    )
    assert (backend.cmd_topic, backend.led_topic, backend.domain, backend.watchdog) == ("cmd_vel", "led", 0, 0.3)
    assert backend.topic(1, backend.cmd_topic) == "/lab/robot1/cmd_vel"
    poses = Ros2PosesConfig.from_table({"kind": "ros2"}, "robots.toml [poses]")
    assert (poses.topic, poses.domain, poses.rate) == ("/robot{id}/pose", None, 10.0)
    assert poses.robot_of("/robot12/pose") == 12 and poses.robot_of("/robot12/odom") is None
    assert poses.wildcard == "/robot$*/pose"


@pytest.mark.parametrize(
    "table, words",
    [
        ({"namespaces": ["robot0"], "cmd_topc": "x"}, "unknown key 'cmd_topc'"),
        ({}, "missing key 'namespaces'"),
        ({"namespaces": []}, "non-empty list"),
        ({"namespaces": ["robot0", "/robot0"]}, "differ"),
        ({"namespaces": ["0robot"]}, "not a ROS 2 name"),
        ({"namespaces": ["robot0"], "cmd_topic": "/cmd_vel"}, "no leading '/'"),
        ({"namespaces": ["robot0"], "domain": -1}, "domain"),
        ({"namespaces": ["robot0"], "domain": True}, "domain"),
        ({"namespaces": ["robot0"], "watchdog": 0}, "watchdog"),
        ({"namespaces": ["robot0"], "distro": "foxy"}, "distro"),
        ({"kind": "epuck2", "namespaces": ["robot0"]}, "kind"),
    ],
)
def test_bad_backend_table_is_one_clear_error(table, words):
    with pytest.raises(HardwareConfigError) as err:
        Ros2BackendConfig.from_table(table, "robots.toml [backend]")
    assert str(err.value).startswith("robots.toml [backend]: ") and words in str(err.value)


@pytest.mark.parametrize(
    "table, words",
    [
        ({"topic": "/pose"}, "{id}"),
        ({"topic": "/{id}/pose"}, "not a ROS 2 name"),
        ({"rate": 0}, "rate"),
        ({"rate": "fast"}, "rate"),
        ({"domain": "0"}, "domain"),
        ({"hz": 10}, "unknown key 'hz'"),
    ],
)
def test_bad_poses_table_is_one_clear_error(table, words):
    with pytest.raises(HardwareConfigError) as err:
        Ros2PosesConfig.from_table(table, "robots.toml [poses]")
    assert str(err.value).startswith("robots.toml [poses]: ") and words in str(err.value)


# --- the emulator's command line, as a real process ----------------------------------------------


@pytest.mark.parametrize("speed", [0.2, -0.2])
def test_circle_headings_follow_the_direction_of_travel(speed):
    poses = circle(5, 0.5, speed)
    dt = 1e-6
    for t in (0.0, 3.0):
        now, later = poses(t), poses(t + dt)
        travel = np.arctan2(later[:, 1] - now[:, 1], later[:, 0] - now[:, 0])
        assert np.allclose(np.remainder(now[:, 2] - travel + np.pi, 2 * np.pi) - np.pi, 0.0, atol=1e-5)
        assert np.allclose(np.hypot(now[:, 0], now[:, 1]), 0.5)


def mocap_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "sim.emulators.mocap", *args]


@pytest.mark.parametrize("args", [["--rate", "0"], ["--topic", "/pose"], ["--domain", "-1"], ["--robots", "two"]])
def test_mocap_cli_bad_input_exits_2_with_one_line(args):
    result = subprocess.run(mocap_cmd(*args), capture_output=True, text=True, timeout=60, cwd=REPO)
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
    assert result.stderr.startswith("python -m sim.emulators.mocap: error:")


def test_mocap_cli_publishes_robots_on_a_circle(router, spawned):
    proc = subprocess.Popen(
        mocap_cmd("--robots", "3", "--rate", "50", "--radius", "0.5", "-e", router.listen[0], "--duration", "30"),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    spawned.append(proc)
    with Ros2PoseSource(Ros2PosesConfig(domain=0), client_of(router)) as source:
        latest = wait_for(lambda: (p := source.latest()) and len(p) == 3 and p, timeout=20)
    assert latest, proc.stderr.read() if proc.poll() is not None else "no poses"
    for pose in latest.values():
        assert math.hypot(pose.x, pose.y) == pytest.approx(0.5)
        tangent = math.atan2(pose.y, pose.x) + math.pi / 2  # driving anticlockwise round the circle
        assert math.remainder(pose.theta - tangent, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    proc.terminate()
    assert proc.wait(timeout=10) == 0
    assert proc.stdout.read().startswith("mocap: 3 robots on /robot{id}/pose at 50 Hz")
