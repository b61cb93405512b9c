"""The ROS 2 message structs (``skincal.data.ros2.messages``) serialise to exactly the bytes of an
independent ROS 2 CDR implementation (rosbags' typestores for Humble and Jazzy), decode back to
themselves, and the decoder drops malformed or oversized samples without raising."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip("cyclonedds")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from skincal.data.ros2 import messages as m  # noqa: E402
from skincal.data.ros2.decode import MAX_BYTES, DropCounts, decode  # noqa: E402

STORES = {"humble": get_typestore(Stores.ROS2_HUMBLE), "jazzy": get_typestore(Stores.ROS2_JAZZY)}
ROS_NAME = {cls: name for name, cls in m.MESSAGE_TYPES.items()}


def to_rosbags(msg, ts):
    """The rosbags message equal to the struct ``msg`` (field by field, recursively)."""
    T = ts.types
    cls = type(msg)
    fields = {}
    for f in dataclasses.fields(msg):
        v = getattr(msg, f.name)
        if dataclasses.is_dataclass(v):
            fields[f.name] = to_rosbags(v, ts)
        elif isinstance(v, list) and v and dataclasses.is_dataclass(v[0]):
            fields[f.name] = [to_rosbags(x, ts) for x in v]
        elif isinstance(v, list) and (not v or isinstance(v[0], float)) and f.name != "name":
            fields[f.name] = np.array(v, dtype=np.float64)
        else:
            fields[f.name] = v
    return T[ROS_NAME[cls]](**fields)


def ros_bytes(msg, store: str) -> bytes:
    ts = STORES[store]
    return bytes(ts.serialize_cdr(to_rosbags(msg, ts), ROS_NAME[type(msg)]))


def header(ns: int = 1_700_000_000_123_456_789, frame: str = "su1") -> m.Header:
    return m.Header(m.Time.from_ns(ns), frame)


EXAMPLES = [
    m.Time(sec=-1, nanosec=999_999_999),
    m.String(data=""),
    m.String(data="<robot name='ärm'>\u2603</robot>"),
    m.JointState(
        header=header(), name=["panda_joint1", "panda_joint2"], position=[0.1, -0.2], velocity=[1e-9, 3.0], effort=[]
    ),  # fmt: skip
    m.JointState(header=header(0, ""), name=[], position=[], velocity=[], effort=[]),  # every array empty
    m.JointState(
        header=header(5, "wörld"),
        name=["Gelenk-ü", "j\u00e9", ""],
        position=[np.pi, -np.inf, 0.0],
        velocity=[],
        effort=[1.0, 2.0, 3.0],
    ),  # fmt: skip
    m.Imu(
        header=header(),
        orientation=m.Quaternion(0, 0, 0, 1),
        orientation_covariance=[-1.0] + [0.0] * 8,
        angular_velocity=m.Vector3(0.1, -0.2, 0.3),
        angular_velocity_covariance=[1e-6] * 9,
        linear_acceleration=m.Vector3(0.0, 0.0, 9.81),
        linear_acceleration_covariance=list(np.arange(9.0)),
    ),
    m.Imu(header=header(1, "Unterarm-links \u03b1"), linear_acceleration=m.Vector3(np.nan, 1e308, -0.0)),
    m.TFMessage(transforms=[]),
    m.TFMessage(
        transforms=[
            m.TransformStamped(
                header=header(2, "panda_link4"),
                child_frame_id="su1",
                transform=m.Transform(m.Vector3(0.01, 0.02, -0.03), m.Quaternion(0.1, 0.2, 0.3, 0.9)),
            ),
            m.TransformStamped(header=header(3, "panda_link7"), child_frame_id="ünit 2"),
        ]
    ),  # fmt: skip
    m.DiagnosticArray(header=header(4, ""), status=[]),
    m.DiagnosticArray(
        header=header(),
        status=[
            m.DiagnosticStatus(
                level=m.OK,
                name="skincal: su1",
                message="calibrated",
                hardware_id="su1",
                values=[m.KeyValue("link", "panda_link4"), m.KeyValue("std (mm)", "0.12")],
            ),
            m.DiagnosticStatus(level=m.WARN, name="skincal: ü", message="", hardware_id="", values=[]),
            m.DiagnosticStatus(level=m.STALE),
        ],
    ),  # fmt: skip
]


@pytest.mark.parametrize("store", sorted(STORES))
@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda x: type(x).__name__)
def test_struct_bytes_equal_rosbags_cdr(msg, store):
    ours = msg.serialize()
    assert ours == ros_bytes(msg, store)
    back = type(msg).deserialize(ours)
    assert back.serialize() == ours


def test_every_type_has_the_ros2_dds_name_and_topics_the_rt_prefix():
    for ros_name, cls in m.MESSAGE_TYPES.items():
        pkg, _, name = ros_name.split("/")
        assert cls.__idl_typename__ == f"{pkg}::msg::dds_::{name}_"
        assert m.ros_type(f"{pkg}::msg::dds_::{name}_") == ros_name
    assert m.dds_topic("/skin/su1/imu") == "rt/skin/su1/imu" and m.ros_topic("rt/skin/su1/imu") == "/skin/su1/imu"
    assert m.ros_topic("rq/node/get_parametersRequest") is None and m.ros_type("Imu") is None


text = st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=12)
floats = st.floats(allow_nan=False, width=64)


@st.composite
def joint_states(draw):
    n = draw(st.integers(0, 9))
    return m.JointState(
        header=m.Header(m.Time(draw(st.integers(-(2**31), 2**31 - 1)), draw(st.integers(0, 2**32 - 1))), draw(text)),
        name=draw(st.lists(text, min_size=n, max_size=n)),
        position=draw(st.lists(floats, min_size=n, max_size=n)),
        velocity=draw(st.lists(floats, min_size=0, max_size=n)),
        effort=draw(st.lists(floats, max_size=3)),
    )


@st.composite
def imus(draw):
    v = lambda: m.Vector3(draw(floats), draw(floats), draw(floats))  # noqa: E731
    return m.Imu(header=m.Header(m.Time(draw(st.integers(0, 2**31 - 1)), draw(st.integers(0, 999_999_999))),
                                 draw(text)),
                 orientation=m.Quaternion(draw(floats), 0.0, 0.0, 1.0),
                 orientation_covariance=draw(st.lists(floats, min_size=9, max_size=9)),
                 angular_velocity=v(), linear_acceleration=v())  # fmt: skip


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(joint_states(), imus()))
def test_random_messages_equal_rosbags_cdr(msg):
    assert msg.serialize() == ros_bytes(msg, "humble")


VALID = {type(x): x.serialize() for x in EXAMPLES}


@settings(max_examples=600, deadline=None)
@given(kind=st.sampled_from(sorted(VALID, key=lambda c: c.__name__)), data=st.data())
def test_decoder_drops_malformed_bytes_and_never_raises(kind, data):
    """Random bytes, truncations and byte flips of valid samples: ``decode`` returns a struct or ``None``
    (counted), never raises; what it returns re-serialises."""
    good = VALID[kind]
    how = data.draw(st.sampled_from(["random", "truncate", "flip", "append"]))
    if how == "random":
        raw = data.draw(st.binary(max_size=400))
    elif how == "truncate":
        raw = good[: data.draw(st.integers(0, max(len(good) - 1, 0)))]
    elif how == "flip":
        i = data.draw(st.integers(0, len(good) - 1))
        raw = good[:i] + bytes([good[i] ^ data.draw(st.integers(1, 255))]) + good[i + 1 :]
    else:
        raw = good + data.draw(st.binary(min_size=1, max_size=40))
    drops = DropCounts()
    msg = decode(kind, raw, drops, "/t")
    if msg is None:
        assert drops.total("malformed") + drops.total("oversized") == 1
    else:
        assert isinstance(msg, kind) and drops.total() == 0
        msg.serialize()


def test_decoder_counts_oversized_and_inconsistent_samples():
    drops = DropCounts()
    big = m.Imu(header=m.Header(frame_id="x" * MAX_BYTES[m.Imu])).serialize()
    assert decode(m.Imu, big, drops, "/skin/a/imu") is None
    bad = m.JointState(name=["a", "b"], position=[1.0], velocity=[]).serialize()  # one position for two names
    assert decode(m.JointState, bad, drops, "/joint_states") is None
    assert decode(m.Imu, b"", drops, "/skin/a/imu") is None
    assert drops.as_dict() == {"/joint_states": {"malformed": 1}, "/skin/a/imu": {"malformed": 1, "oversized": 1}}
    assert decode(m.Imu, EXAMPLES[6].serialize(), drops, "/skin/a/imu") == EXAMPLES[6]
    assert drops.total() == 3


def test_decoder_reads_big_endian_cdr_and_refuses_a_string_beyond_the_data():
    from cyclonedds.idl._support import Endianness

    msg = EXAMPLES[3]
    big = msg.serialize(endianness=Endianness.Big)
    assert big[:2] == b"\x00\x00" and decode(m.JointState, big) == msg
    raw = bytearray(m.String(data="abc").serialize())
    raw[4] = 200  # the string's length: 200 bytes, beyond the sample
    drops = DropCounts()
    assert decode(m.String, bytes(raw), drops, "/robot_description") is None and drops.total("malformed") == 1


@pytest.mark.slow
def test_fuzz_10000_malformed_samples_per_type_never_crash():
    """The issue's target: 10,000 malformed samples per message type (seeded: random bytes, truncations,
    byte flips, a length field set huge, splices of two valid samples), each decoded or dropped."""
    rng = np.random.default_rng(29)
    samples = {}
    for x in EXAMPLES:
        samples.setdefault(type(x), []).append(x.serialize())
    for kind, goods in samples.items():
        drops, decoded = DropCounts(), 0
        for k in range(10_000):
            good = goods[k % len(goods)]
            how = k % 5
            if how == 0:
                raw = rng.bytes(int(rng.integers(0, 300)))
            elif how == 1:
                raw = good[: int(rng.integers(0, len(good)))]
            elif how == 2:
                b = bytearray(good)
                for i in rng.integers(0, len(b), size=int(rng.integers(1, 4))):
                    b[i] ^= int(rng.integers(1, 256))
                raw = bytes(b)
            elif how == 3:
                b = bytearray(good)
                i = int(rng.integers(4, max(len(b) - 4, 5))) & ~3
                b[i : i + 4] = int(rng.integers(2**20, 2**32)).to_bytes(4, "little")
                raw = bytes(b)
            else:
                other = goods[int(rng.integers(0, len(goods)))]
                raw = good[: int(rng.integers(0, len(good)))] + other[int(rng.integers(0, len(other))) :]
            msg = decode(kind, raw, drops, "/fuzz")
            decoded += msg is not None
        assert decoded + drops.total() == 10_000, kind
