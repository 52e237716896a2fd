"""Every file the tool reads, given random bytes, truncations and byte flips of a good file:
each read either succeeds or raises the reader's own one-line error naming the file, never
another exception (a ``UnicodeDecodeError``, a ``KeyError``, a ``TypeError``...).

Readers: scenarios (``load_scenario``), the ``line: file:`` it names (CSV and GeoJSON), plan
files (``load_plan``), flown telemetry (CSV and ``.tlog``) and image logs. The draws are
seeded, so a failure is reproduced by running the test again.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml

from gcs.errors import InputFileError
from gcs.telemetry import load_images, load_telemetry
from mavlink.errors import LinkError
from mavlink.link.camera import IMAGE_COLUMNS
from planner.errors import FileFieldError
from planner.planfile import load_plan
from planner.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "tests" / "mavlink" / "data" / "link_reach_avoid.yaml"
PLAN = ROOT / "tests" / "mavlink" / "data" / "reach_avoid_2.plan.json"

#: Draws per kind (random bytes, truncations, byte flips) and reader.
DRAWS = 80

_LINE_SCENARIO = """
name: line
origin: {lat: 47.397742, lon: 8.545594, alt: 488.0}
workspace: {min: [-150, -150, 0.5], max: [250, 250, 20]}
line:
  file: FILE
  pole: {radius_m: 0.4, height_m: 12}
  conductors: {half_width_m: 1.8, z: [9, 12], clearance_m: 1.0}
  inspection: {standoff_m: 1.5, depth_m: 2.2, length_m: 5, z: [9.5, 12.5], side: right}
vehicles:
  - {name: d1, start: [-12, -12, 8]}
limits: {v_max_m_s: 5, a_max_m_s2: 3}
timing: {horizon_s: 60, segment_s: 3, Ts_s: 0.5}
spec:
  - formula: eventually[0, 55] always[0, 2] inside(d1, insp1)
"""

_POLES_CSV = "id,lat,lon\nP1,47.397742,8.545594\nP2,47.397742,8.546\nP3,47.3978,8.5465\n"
_POLES_GEOJSON = (
    '{"type": "FeatureCollection", "features": ['
    '{"type": "Feature", "geometry": {"type": "Point", "coordinates": [8.545594, 47.397742]}},'
    '{"type": "Feature", "geometry": {"type": "Point", "coordinates": [8.546, 47.397742]}}]}'
)
_TELEMETRY = "t,vehicle,x,y,z,yaw\n" + "".join(
    f"{i * 0.1:.1f},d{k},{i * 0.01:.2f},1.0,1.5,0.1\n" for i in range(20) for k in (1, 2)
)
_IMAGES = (
    ",".join(IMAGE_COLUMNS)
    + "\n"
    + "".join(
        ",".join(
            {
                "vehicle": "d1",
                "t_s": f"{i}.0",
                "lat_deg": "47.3977",
                "lon_deg": "8.5456",
                "alt_amsl_m": "500",
                "rel_alt_m": "12",
                "qw": "1",
                "qx": "0",
                "qy": "0",
                "qz": "0",
                "index": str(i),
                "ok": "1",
                "component": "100",
                "file_url": "",
            }[c]
            for c in IMAGE_COLUMNS
        )
        + "\n"
        for i in range(4)
    )
)


def _variants(good: bytes, seed: int) -> list[bytes]:
    """Random bytes, truncations and 1-4 byte flips of ``good`` (seeded)."""
    rng = random.Random(seed)
    out = [b"", b"\x00", b"PK\x03\x04" + good, good[: len(good) // 2]]
    for _ in range(DRAWS):
        out.append(rng.randbytes(rng.randrange(1, 400)))
    for _ in range(DRAWS):
        out.append(good[: rng.randrange(0, len(good))])
    for _ in range(DRAWS):
        b = bytearray(good)
        for _ in range(rng.randrange(1, 5)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        out.append(bytes(b))
    return out


def _expect_one_line(
    read: Callable[[], object], names: tuple[str, ...], allowed: tuple[type, ...]
) -> None:
    """``read()`` succeeds or raises one of ``allowed`` in one line naming one of ``names``
    (a line file's poles may be read and then break the scenario that names them)."""
    try:
        read()
    except allowed as exc:
        msg = str(exc)
        assert "\n" not in msg.strip(), msg
        assert any(n in msg for n in names), msg


@pytest.mark.parametrize(
    ("kind", "seed"),
    [("scenario", 1), ("plan", 2), ("line_csv", 3), ("line_geojson", 4)],
)
def test_planner_readers_raise_only_their_one_line_error(
    kind: str, seed: int, tmp_path: Path
) -> None:
    if kind == "scenario":
        good = SCENARIO.read_bytes()
        name, target = "s.yaml", tmp_path / "s.yaml"
    elif kind == "plan":
        good = PLAN.read_bytes()
        name, target = "p.plan.json", tmp_path / "p.plan.json"
    else:
        suffix = "csv" if kind == "line_csv" else "geojson"
        good = (_POLES_CSV if suffix == "csv" else _POLES_GEOJSON).encode()
        name, target = f"poles.{suffix}", tmp_path / f"poles.{suffix}"
        (tmp_path / "s.yaml").write_text(_LINE_SCENARIO.replace("FILE", name))
    for blob in _variants(good, seed):
        target.write_bytes(blob)
        if kind == "plan":
            _expect_one_line(lambda: load_plan(target), (name,), (FileFieldError,))
        else:
            _expect_one_line(
                lambda: load_scenario(tmp_path / "s.yaml"), (name, "s.yaml"), (FileFieldError,)
            )


@pytest.mark.parametrize(("kind", "seed"), [("telemetry", 5), ("images", 6), ("tlog", 7)])
def test_flight_log_readers_raise_only_their_one_line_error(
    kind: str, seed: int, tmp_path: Path
) -> None:
    plan = load_plan(PLAN)
    if kind == "tlog":
        good = bytes(random.Random(seed).randbytes(300))
        target = tmp_path / "f.tlog"
    else:
        good = (_TELEMETRY if kind == "telemetry" else _IMAGES).encode()
        target = tmp_path / f"{kind}.csv"
    for blob in _variants(good, seed):
        target.write_bytes(blob)
        if kind == "images":
            _expect_one_line(lambda: load_images(target, plan), (target.name,), (InputFileError,))
        else:
            _expect_one_line(
                lambda: load_telemetry(target, plan, t0_unix_s=1.0e9),
                (target.name,),
                (InputFileError, LinkError),
            )


def test_the_good_files_of_the_fuzz_are_read(tmp_path: Path) -> None:
    # The fuzz starts from files that read: otherwise it would only ever test refusals.
    (tmp_path / "poles.csv").write_text(_POLES_CSV)
    (tmp_path / "poles.geojson").write_text(_POLES_GEOJSON)
    for name in ("poles.csv", "poles.geojson"):
        (tmp_path / "s.yaml").write_text(_LINE_SCENARIO.replace("FILE", name))
        assert load_scenario(tmp_path / "s.yaml").region("insp1") is not None
    (tmp_path / "t.csv").write_text(_TELEMETRY)
    assert set(load_telemetry(tmp_path / "t.csv").vehicles) == {"d1", "d2"}
    (tmp_path / "i.csv").write_text(_IMAGES)
    assert len(load_images(tmp_path / "i.csv", load_plan(PLAN))["d1"]) == 4
    assert yaml.safe_load(SCENARIO.read_text())["name"]


@pytest.mark.parametrize(
    ("content", "says"),
    [
        (b"PK\x03\x04\x14\x00\x08\x00" + bytes(64), "a zip archive (a KMZ or XLSX file?)"),
        ("id,lat,lon\nP1,47.3977,8.5456\n".encode("utf-16"), "not UTF-8 text"),
        (b"id,lat,lon\nP1,47.3977,8.5456\x00\n", "a binary file"),
        (None, "Is a directory"),
    ],
)
def test_a_line_file_that_is_not_text_is_one_line_naming_it(
    content: bytes | None, says: str, tmp_path: Path
) -> None:
    # (a CSV name: a file named .kml or .kmz is read as KML, tests/planner/test_kml.py)
    target = tmp_path / "poles.csv"
    if content is None:
        target.mkdir()
    else:
        target.write_bytes(content)
    (tmp_path / "s.yaml").write_text(_LINE_SCENARIO.replace("FILE", "poles.csv"))
    with pytest.raises(FileFieldError) as err:
        load_scenario(tmp_path / "s.yaml")
    msg = str(err.value)
    assert "line.file" in msg and "poles.csv" in msg and says in msg and "\n" not in msg
