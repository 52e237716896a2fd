"""URLs, PX4 modes and the error tree: pure functions, checked against pymavlink's definitions."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mav

from mavlink.errors import LinkError, MissionError, MissionResult, UrlError
from mavlink.link.urls import (
    ConnectionUrl,
    Scheme,
    default_sysid,
    default_url,
    default_vehicle_port,
    parse_url,
)
from mavlink.px4_modes import (
    AutoSubMode,
    MainMode,
    Px4Mode,
    UnknownModeError,
    decode_custom_mode,
    encode_custom_mode,
    parse_mode,
    set_mode_params,
)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("udpin://0.0.0.0:14540", ConnectionUrl(Scheme.UDPIN, host="0.0.0.0", port=14540)),
        ("udpout://127.0.0.1:14580", ConnectionUrl(Scheme.UDPOUT, host="127.0.0.1", port=14580)),
        (
            "tcpout://gcs.example.org:5760",
            ConnectionUrl(Scheme.TCPOUT, host="gcs.example.org", port=5760),
        ),
        ("tcpin://[::1]:5760", ConnectionUrl(Scheme.TCPIN, host="::1", port=5760)),
        (
            "serial:///dev/ttyUSB0:57600",
            ConnectionUrl(Scheme.SERIAL, device="/dev/ttyUSB0", baud_rate=57600),
        ),
    ],
)
def test_valid_urls_parse_and_print_back(text: str, expected: ConnectionUrl) -> None:
    url = parse_url(text)
    assert url == expected
    assert str(url) == text
    assert parse_url(str(url)) == url


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("", "empty"),
        ("0.0.0.0:14540", "SCHEME://"),
        ("udp://0.0.0.0:14540", "unknown scheme 'udp'"),
        ("udpin://0.0.0.0", "HOST:PORT"),
        ("udpin://:14540", "missing host"),
        ("udpin://0.0.0.0:70000", "port '70000'"),
        ("udpin://0.0.0.0:0", "port '0'"),
        ("udpin://0.0.0.0:abc", "port 'abc'"),
        ("udpin://bad_host!:14540", "neither an IP address"),
        ("serial:///dev/ttyUSB0", "serial://DEVICE:BAUD"),
        ("serial:///dev/ttyUSB0:12345", "baud rate '12345'"),
    ],
)
def test_bad_urls_are_one_clear_error(text: str, fragment: str) -> None:
    with pytest.raises(UrlError) as info:
        parse_url(text, vehicle="d2")
    msg = str(info.value)
    assert fragment in msg
    assert msg.startswith("vehicle d2: bad connection URL")
    assert isinstance(info.value, LinkError) and isinstance(info.value, ValueError)


def test_px4_sitl_port_convention() -> None:
    assert [default_url(i) for i in range(3)] == [
        "udpin://0.0.0.0:14540",
        "udpin://0.0.0.0:14541",
        "udpin://0.0.0.0:14542",
    ]
    assert [default_sysid(i) for i in range(3)] == [1, 2, 3]
    assert default_vehicle_port(3) == 14583
    with pytest.raises(UrlError):
        default_sysid(255)


def test_custom_mode_matches_px4_bit_layout() -> None:
    # Reference values from PX4's px4_custom_mode.h union layout: main in byte 2, sub in byte 3.
    assert encode_custom_mode(Px4Mode.OFFBOARD) == 6 << 16 == 393216
    assert encode_custom_mode(Px4Mode.AUTO_MISSION) == (4 << 16) | (4 << 24) == 67371008
    assert encode_custom_mode(Px4Mode.AUTO_LOITER) == 50593792
    for mode in Px4Mode:
        assert decode_custom_mode(encode_custom_mode(mode)) is mode
    assert Px4Mode.AUTO_RTL.label == "AUTO.RTL" and Px4Mode.OFFBOARD.label == "OFFBOARD"
    assert Px4Mode.AUTO_LAND.main is MainMode.AUTO and Px4Mode.AUTO_LAND.sub == AutoSubMode.LAND


def test_the_mock_and_the_ground_station_encode_every_px4_mode_alike() -> None:
    # two enums on purpose (the vehicle's side shares only the wire with the client it
    # tests): the same modes, the same (main, sub) custom-mode pairs
    from mavlink.mock.sim.px4 import Px4Mode as MockMode

    assert [m.name for m in MockMode] == [m.name for m in Px4Mode]
    for mode in Px4Mode:
        main, sub = MockMode[mode.name].value
        assert (int(mode.value[0]), int(mode.value[1])) == (main, sub)
        assert decode_custom_mode(encode_custom_mode(mode)) is mode


@pytest.mark.parametrize(
    "value", [0, 9 << 16, (4 << 16) | (9 << 24), (6 << 16) | 1, (3 << 16) | (1 << 24), -1]
)
def test_unknown_custom_modes_are_rejected(value: int) -> None:
    with pytest.raises(UnknownModeError, match="not"):
        decode_custom_mode(value)


def test_set_mode_params_follow_do_set_mode() -> None:
    p1, p2, p3 = set_mode_params(Px4Mode.AUTO_LAND)
    assert int(p1) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert (p2, p3) == (4.0, 6.0)
    assert set_mode_params(Px4Mode.OFFBOARD, armed=True) == (
        float(mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_SAFETY_ARMED),
        6.0,
        0.0,
    )


def test_mode_names_parse() -> None:
    assert parse_mode("hold") is Px4Mode.AUTO_LOITER
    assert parse_mode("AUTO.MISSION") is Px4Mode.AUTO_MISSION
    assert parse_mode("offboard") is Px4Mode.OFFBOARD
    with pytest.raises(UnknownModeError, match="unknown PX4 mode 'hover'"):
        parse_mode("hover")


def test_errors_name_vehicle_and_url() -> None:
    err = LinkError("no heartbeat", vehicle="d1", url="udpin://0.0.0.0:14540")
    assert str(err) == "vehicle d1 (udpin://0.0.0.0:14540): no heartbeat"
    m = MissionError(
        MissionResult.MISMATCH, "verify_mission", "item 3 differs", vehicle="d2", url="u"
    )
    assert (m.result, m.origin) == (MissionResult.MISMATCH, "verify_mission")
    assert str(m) == "vehicle d2 (u): verify_mission: mismatch: item 3 differs"
    assert isinstance(m, LinkError)
