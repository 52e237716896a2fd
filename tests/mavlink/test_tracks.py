"""Flown tracks with their heading: the shorter turn between samples, the mission frame's yaw
from the vehicle's NED yaw, and the track CSV (written, read back, and read when older files
have no heading column)."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from gcs.errors import InputFileError
from gcs.telemetry import load_telemetry
from mavlink.errors import MissingHeadingError
from mavlink.tracks import (
    CSV_COLUMNS,
    FlownTrack,
    track_from_rows,
    vehicle_instants,
    write_tracks_csv,
)
from planner.frames import GeodeticPoint, ned_vector_to_enu

MISSION = GeodeticPoint(47.397742, 8.545594, 488.0)
# a vehicle whose EKF origin is 3 km east and 2 km north: its north is turned against ours
AWAY = GeodeticPoint(47.41573, 8.58535, 495.0)


def _track(yaw_deg: list[float] | None, t: list[float] | None = None) -> FlownTrack:
    ts = np.asarray(t if t is not None else range(len(yaw_deg or [0.0, 0.0])), dtype=float)
    pos = np.column_stack([ts, -ts, np.full(ts.size, 5.0)])
    yaw = None if yaw_deg is None else np.radians(np.asarray(yaw_deg, dtype=float))
    return FlownTrack("d1", ts, pos, np.zeros_like(pos), pos.copy(), yaw)


def test_the_heading_between_samples_turns_the_shorter_way_and_is_held_outside() -> None:
    tr = _track([170.0, -170.0, -90.0])
    got = np.degrees(tr.yaw(np.array([-1.0, 0.0, 0.5, 1.0, 1.5, 9.0])))
    # through 180 (not back through 0), wrapped to (-180, 180]
    np.testing.assert_allclose(got, [170.0, 170.0, 180.0, -170.0, -130.0, -90.0], atol=1e-9)
    assert np.all((got > -180.0) & (got <= 180.0))


def test_samples_without_a_heading_are_skipped_and_none_at_all_is_said() -> None:
    tr = _track([math.nan, 10.0, math.nan, 30.0])
    np.testing.assert_allclose(np.degrees(tr.yaw(np.array([0.0, 2.0, 3.0]))), [10, 20, 30])
    np.testing.assert_array_equal(tr.heading_t_s, [1.0, 3.0])
    sig = tr.signal(np.array([2.0]), heading=True)
    assert sig.shape == (1, 4) and sig[0, 3] == pytest.approx(math.radians(20.0))
    for bare in (_track(None), _track([math.nan, math.nan])):
        assert not bare.has_heading
        assert bare.signal(np.array([0.5])).shape == (1, 3)
        with pytest.raises(MissingHeadingError, match=r"^vehicle d1: the telemetry has no heading"):
            bare.signal(np.array([0.5]), heading=True)
        with pytest.raises(MissingHeadingError, match="vehicle d1"):
            bare.resample(0.5, 1.0, heading=True)


def test_recorded_ned_yaw_becomes_the_mission_frames_yaw_by_the_positions_rotation() -> None:
    yaw_ned = np.radians([0.0, 90.0, 200.0, -45.0, math.nan])
    rows = np.column_stack(
        [np.arange(5.0) + 100.0, np.zeros((5, 6)), yaw_ned]
    )  # (t, n, e, d, vn, ve, vd, yaw)
    for origin in (MISSION, AWAY):
        tr = track_from_rows("d1", rows, 100.0, MISSION, origin)
        np.testing.assert_array_equal(tr.t_s, np.arange(5.0))
        assert tr.yaw_enu_rad is not None and math.isnan(tr.yaw_enu_rad[-1])
        # independently: the heading's unit vector (north, east) through the velocity rotation
        h = np.column_stack([np.cos(yaw_ned[:4]), np.sin(yaw_ned[:4]), np.zeros(4)])
        e = ned_vector_to_enu(h, MISSION, origin)
        want = np.arctan2(e[:, 1], e[:, 0])
        err = np.angle(np.exp(1j * (tr.yaw_enu_rad[:4] - want)))
        # (the two tangent planes 3.6 km apart are tilted by 0.03 deg: a projected angle
        # moves by 1e-7 rad with the heading, the yaw conversion turns by one angle)
        assert np.abs(err).max() < 1e-6
    # north in the vehicle's frame is +y (90 deg ENU) at the mission origin, slightly turned away
    away = track_from_rows("d1", rows, 100.0, MISSION, AWAY).yaw_enu_rad
    assert away is not None and 1e-4 < abs(away[0] - math.pi / 2) < math.radians(0.1)
    # rows recorded without a yaw (or none known): no heading
    assert track_from_rows("d1", rows[:, :7], 100.0, MISSION, MISSION).yaw_enu_rad is None
    blind = rows.copy()
    blind[:, 7] = math.nan
    assert track_from_rows("d1", blind, 100.0, MISSION, MISSION).yaw_enu_rad is None


def test_the_track_csv_keeps_the_heading_and_leaves_the_unknown_empty(tmp_path: Path) -> None:
    with_yaw = _track([math.nan, 170.0, -170.0, 12.5])
    without = FlownTrack("d2", *(getattr(_track(None, [0.0, 1.0]), f) for f in (
        "t_s", "pos_enu_m", "vel_enu_m_s", "pos_ned_m")))  # fmt: skip
    path = write_tracks_csv(tmp_path / "flight.csv", {"d1": with_yaw, "d2": without})
    with path.open(encoding="utf-8") as f:
        rows = list(csv.reader(f))
    assert rows[0] == list(CSV_COLUMNS) and rows[0][-1] == "yaw_enu_rad"
    assert [r[-1] for r in rows[1:]][:2] == ["", repr(math.radians(170.0))]
    assert all(r[-1] == "" for r in rows[1:] if r[0] == "d2")
    back = load_telemetry(path).vehicles
    assert back["d2"].yaw_enu_rad is None
    got = back["d1"].yaw_enu_rad
    assert got is not None and math.isnan(got[0])
    np.testing.assert_array_equal(got[1:], with_yaw.yaw_enu_rad[1:])  # type: ignore[index]
    np.testing.assert_array_equal(back["d1"].pos_enu_m, with_yaw.pos_enu_m)


def test_an_older_track_csv_without_the_heading_column_loads_without_a_heading(
    tmp_path: Path,
) -> None:
    old = tmp_path / "old.csv"
    header = [c for c in CSV_COLUMNS if c != "yaw_enu_rad"]
    lines = [",".join(header)]
    lines += [f"d1,{t},{t},0,5,0,0,0,0,{t},-5" for t in (0.0, 0.5, 1.0)]
    old.write_text("\n".join(lines) + "\n", encoding="utf-8")
    tr = load_telemetry(old).vehicles["d1"]
    assert tr.yaw_enu_rad is None and not tr.has_heading
    np.testing.assert_array_equal(tr.t_s, [0.0, 0.5, 1.0])


def test_a_users_yaw_column_is_read_and_a_bad_value_named(tmp_path: Path) -> None:
    good = tmp_path / "good.csv"
    good.write_text("t,vehicle,x,y,z,yaw\n0,d1,0,0,1,0.5\n1,d1,1,0,1,\n2,d1,2,0,1,-3\n")
    tr = load_telemetry(good).vehicles["d1"]
    np.testing.assert_array_equal(tr.heading_t_s, [0.0, 2.0])
    bad = tmp_path / "bad.csv"
    bad.write_text("t,vehicle,x,y,z,yaw\n0,d1,0,0,1,0.5\n1,d1,1,0,1,east\n")
    with pytest.raises(InputFileError, match=r"bad\.csv: line 3: column yaw: not a number: 'east'"):
        load_telemetry(bad)
    inf = tmp_path / "inf.csv"
    inf.write_text("t,vehicle,x,y,z,yaw\n0,d1,0,0,1,inf\n")
    with pytest.raises(InputFileError, match=r"line 2: column yaw: must be finite"):
        load_telemetry(inf)


# -- the vehicle's own instants (time_boot_ms) carried onto the ground station's clock


def _brute_instants(t_recv: np.ndarray, t_boot: np.ndarray, half: int) -> np.ndarray:
    """The definition, sample by sample: the vehicle's time plus the fastest delivery among
    the ``half`` samples either side."""
    off = t_recv - t_boot
    n = len(off)
    return np.array(
        [t_boot[i] + min(off[max(0, i - half) : min(n, i + half + 1)]) for i in range(n)]
    )


def test_vehicle_instants_take_the_jitter_out_and_match_their_definition() -> None:
    rng = np.random.default_rng(3)
    t_boot = np.arange(0.0, 60.0, 0.02) + 12.345  # 50 Hz, since the vehicle's boot
    # 5 ms of constant latency, and a busy ground station's jitter (mean 40 ms, tail 0.4 s)
    jitter = rng.exponential(0.04, t_boot.size)
    t_recv = np.maximum.accumulate(1000.0 + t_boot + 0.005 + jitter)  # delivered in order
    got = vehicle_instants(t_recv, t_boot)
    truth = 1000.0 + t_boot  # the instant each sample was taken, on the receiver's clock
    # only the latency no sample escapes is left (5 ms and the luckiest sample's jitter)
    assert np.max(np.abs(got - truth - 0.005)) < 0.005
    assert np.mean(t_recv - truth) > 0.04  # what the receipt times carried
    assert np.allclose(got, _brute_instants(t_recv, t_boot, half=125), atol=1e-12)


def test_vehicle_instants_follow_a_clock_that_runs_at_another_rate() -> None:
    # 50 ppm apart (an oscillator's worth) over 10 minutes: 30 ms in all, which a single
    # offset would leave at one end
    t_boot = np.arange(0.0, 600.0, 0.05)
    t_recv = 5.0 + t_boot * (1.0 + 50e-6) + 0.002
    got = vehicle_instants(t_recv, t_boot)
    # no jitter here: the instants are the receipt times (the constant latency stays)
    assert np.max(np.abs(got - t_recv)) < 2e-4
    one_offset = t_boot + np.min(t_recv - t_boot)
    assert np.max(np.abs(one_offset - t_recv)) > 0.025


def test_vehicle_instants_unwrap_time_boot_ms_and_give_up_on_a_reboot() -> None:
    wrap = 2.0**32 * 1e-3
    t_boot = np.arange(wrap - 1.0, wrap + 1.0, 0.1)
    t_recv = 7.0 + t_boot + 0.01
    got = vehicle_instants(t_recv, np.mod(t_boot, wrap))
    assert np.allclose(got, t_recv)
    rebooted = np.concatenate([np.arange(100.0, 101.0, 0.1), np.arange(0.0, 1.0, 0.1)])
    t_recv = np.arange(rebooted.size) * 0.1
    assert np.array_equal(vehicle_instants(t_recv, rebooted), t_recv)
    assert vehicle_instants(np.array([3.0]), np.array([1.0])).tolist() == [3.0]
