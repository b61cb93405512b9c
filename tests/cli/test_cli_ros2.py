"""``skincal ros2`` / ``ros2-play`` usage: what is joined is said, bad input is one line and exit 2,
outputs are never clobbered, and the default configuration keeps DDS on the loopback interface."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest

pytest.importorskip("cyclonedds")

from skincal.cli import main  # noqa: E402
from skincal.data.ros2.participant import LOOPBACK, config_xml, domain_id  # noqa: E402
from skincal.errors import ConfigError  # noqa: E402


def test_the_default_configuration_is_loopback_only_without_multicast():
    root = ET.fromstring(config_xml())
    general = root.find("Domain/General")
    assert general is not None and general.findtext("AllowMulticast") == "false"
    (nic,) = general.findall("Interfaces/NetworkInterface")
    assert nic.attrib == {"address": LOOPBACK}
    peers = [p.attrib["address"] for p in root.findall("Domain/Discovery/Peers/Peer")]
    assert peers == [LOOPBACK]  # discovery by unicast to this machine only
    other = ET.fromstring(config_xml("eth0"))
    assert other.find("Domain/General/Interfaces/NetworkInterface").attrib == {"name": "eth0"}
    assert other.find("Domain/General/AllowMulticast") is None  # Cyclone's default: ROS 2's multicast discovery


def test_domain_comes_from_the_option_else_ros_domain_id():
    assert domain_id(None, {}) == 0 and domain_id(None, {"ROS_DOMAIN_ID": " 42 "}) == 42
    assert domain_id(7, {"ROS_DOMAIN_ID": "42"}) == 7
    for bad_env, bad in (({"ROS_DOMAIN_ID": "abc"}, None), ({}, 233), ({}, -1)):
        with pytest.raises(ConfigError):
            domain_id(bad, bad_env)


@pytest.mark.adversarial
@pytest.mark.parametrize(
    ("argv", "env", "message"),
    [
        (["ros2", "--domain", "300"], {}, "error: domain id 300: must be 0-232"),
        (["ros2", "--duration", "1"], {"ROS_DOMAIN_ID": "x\x1b[31m"},
         "error: ROS_DOMAIN_ID='x\\x1b[31m' is not a domain id (an integer 0-232)"),
        (["ros2", "--interface", "no-such-nic0"], {}, "error: --interface 'no-such-nic0': no such network interface"),
        (["ros2", "--target", "3"], {}, "error: --target '3'"),
        (["ros2", "--duration", "-1"], {}, "error: --duration -1.0: a number of seconds > 0"),
        (["ros2-play", "missing.h5"], {}, "error: missing.h5: no such file"),
        (["ros2-play", "missing.h5", "--origin-ns", "99999999999999999999"], {}, "error: --origin-ns 9999999"),
        (["ros2-play", "missing.h5", "--origin-ns", "-5"], {}, "error: --origin-ns -5: ns since the epoch"),
        (["ros2", "--record", "/nonexist/dir/bag", "--duration", "1"], {}, "error: --record /nonexist/dir/bag:"),
        # root may "access" /proc for writing, yet no folder can be made there: tried, not assumed
        (["ros2", "--record", "/proc/bag", "--duration", "1"], {}, "error: --record /proc/bag: /proc is not a"),
    ],
)  # fmt: skip
def test_bad_input_is_one_line_and_exit_2(argv, env, message, monkeypatch, capsys, tmp_path):
    monkeypatch.chdir(tmp_path)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(message) and "\n" not in err and "Traceback" not in err, err


@pytest.mark.adversarial
def test_outputs_are_never_clobbered(tmp_path, capsys):
    (tmp_path / "r.json").write_text("{}")
    (tmp_path / "bag").mkdir()
    assert main(["ros2", "--result", str(tmp_path / "r.json"), "--duration", "1"]) == 2
    assert "exists" in capsys.readouterr().err and (tmp_path / "r.json").read_text() == "{}"
    assert main(["ros2", "--record", str(tmp_path / "bag"), "--duration", "1"]) == 2
    assert "exists" in capsys.readouterr().err


def test_an_empty_graph_ends_with_one_line_and_no_result(tmp_path, capsys):
    """Nothing published on the domain: at --duration the command says what it waited for, writes nothing."""
    import random

    out = tmp_path / "r.json"
    domain = random.Random().randint(1, 200)
    assert main(["ros2", "--robot", "panda", "--domain", str(domain), "--duration", "0.5", "--result", str(out)]) == 2
    captured = capsys.readouterr()
    assert f"joined ROS 2 domain {domain} on the loopback interface (127.0.0.1), multicast off" in captured.out
    assert captured.err.strip() == ("error: ended (duration) before the calibrator started: no joint states on "
                                    "/joint_states and sensor_msgs/Imu topics")  # fmt: skip
    assert not out.exists()


def test_another_interface_is_named_when_joined(capsys):
    import random
    import socket

    names = [n for _, n in socket.if_nameindex()]
    if "lo" not in names:
        pytest.skip("no interface named lo")
    domain = random.Random().randint(1, 200)
    assert main(["ros2", "--robot", "panda", "--interface", "lo", "--domain", str(domain), "--duration", "0.3"]) == 2
    assert f"joined ROS 2 domain {domain} on interface lo (127.0.0.1" in capsys.readouterr().out


@pytest.mark.adversarial
def test_a_robot_description_no_calibrator_could_use_is_refused_before_publishing(tmp_path, capsys):
    """``ros2-play --robot-description``: not XML, or a URDF whose chain lacks the dataset's joints, is one line
    and exit 2 before the domain is joined (it was published as it was; the calibrator then dropped every joint
    state as another robot's)."""
    from registry_robots import registry_urdf

    data = tmp_path / "s.h5"
    assert main(["simulate", "--robot", "panda", "--protocol", "fast", "--units", "1", "--placement", "random",
                 "--noise", "none", "-o", str(data)]) == 0  # fmt: skip
    capsys.readouterr()
    (tmp_path / "bad.urdf").write_text("not xml")
    cases = ((tmp_path / "bad.urdf", "not a valid URDF"),
             (registry_urdf("ur5"), "lacks the dataset's joint(s) panda_joint1"))  # fmt: skip
    for path, message in cases:
        assert main(["ros2-play", str(data), "--robot-description", str(path), "--domain", "231"]) == 2
        err = capsys.readouterr()
        assert message in err.err and "\n" not in err.err.strip() and "joined" not in err.out, err
