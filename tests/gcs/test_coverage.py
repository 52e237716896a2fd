"""The coverage report against pictures made by hand: where from, which way the camera looked
(gcs.plot.coverage, mavlink.link.camera), the image log's CSV, and ``gcs verify --images``.

The pictures are built independently of the module: positions through pymap3d, the camera's
attitude through scipy's rotations (yaw about down, then pitch, as a gimbal's q in NED).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pymap3d
import pytest
from scipy.spatial.transform import Rotation

from gcs.cli import main
from gcs.errors import InputFileError
from gcs.plot.coverage import compute_coverage, coverage_figure, coverage_lines
from gcs.telemetry import load_images
from mavlink.link.camera import CameraInfo, CapturedImage, write_images_csv
from planner.planfile import load_plan


@pytest.fixture(scope="module")
def face_plan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """d1 hovers in insp1 facing pole1 (``gcs plan``, tests.gcs.face_plan)."""
    from tests.gcs.face_plan import write_face_plan

    return write_face_plan(tmp_path_factory.mktemp("face"))


def _picture(
    plan, at_enu: np.ndarray, yaw_off_deg: float = 0.0, pitch_deg: float | None = None, **kw
) -> CapturedImage:
    """A picture from ``at_enu`` looking at pole1's axis at the camera's height (turned
    ``yaw_off_deg`` to the right of it; ``pitch_deg`` instead of level)."""
    o = plan.origin
    lat, lon, alt = pymap3d.enu2geodetic(*at_enu, o.lat_deg, o.lon_deg, o.alt_m)
    c = plan.region("pole1").center_enu_m
    d = c[:2] - at_enu[:2]
    compass = math.degrees(math.atan2(d[0], d[1])) + yaw_off_deg  # clockwise from north
    pitch = 0.0 if pitch_deg is None else pitch_deg
    x, y, z, w = Rotation.from_euler("ZYX", [compass, pitch, 0.0], degrees=True).as_quat()
    fields = dict(
        vehicle="d1", t_s=kw.pop("t_s", 6.0), lat_deg=float(lat), lon_deg=float(lon),
        alt_amsl_m=float(alt), rel_alt_m=float(at_enu[2]), q_wxyz=(w, x, y, z),
        index=kw.pop("index", 0),
    )  # fmt: skip
    fields.update(kw)
    return CapturedImage(**fields)


def _in_place(plan) -> np.ndarray:
    """The planned position mid-hover in insp1 (the plan's own sample)."""
    tr = plan.vehicle("d1").trajectory
    t = np.arange(0, plan.horizon_s, 0.05)
    inside = plan.region("insp1").contains(tr.position(t))
    return tr.position(np.array([t[inside][len(t[inside]) // 2]]))[0]


def test_the_optical_axis_is_the_attitudes_forward_axis_in_enu(face_plan: Path) -> None:
    plan = load_plan(face_plan)
    im = _picture(plan, np.array([1.0, 2.0, 10.0]), yaw_off_deg=0.0, pitch_deg=-30.0)
    heading, pitch = im.yaw_pitch_deg()
    c = plan.region("pole1").center_enu_m
    want = math.degrees(math.atan2(c[0] - 1.0, c[1] - 2.0)) % 360.0
    assert heading == pytest.approx(want, abs=1e-9)
    assert pitch == pytest.approx(-30.0, abs=1e-9)
    np.testing.assert_allclose(np.linalg.norm(im.axis_enu()), 1.0)
    np.testing.assert_allclose(im.position_enu_m(plan.origin), [1.0, 2.0, 10.0], atol=1e-6)


def test_a_picture_counts_from_the_place_facing_the_target_within_the_tolerance(
    face_plan: Path,
) -> None:
    plan = load_plan(face_plan)
    p = _in_place(plan)
    c = plan.region("pole1").center_enu_m
    good = _picture(plan, p, 0.0, index=0)
    off10 = _picture(plan, p, 10.0, index=1)
    off20 = _picture(plan, p, -20.0, index=2)
    failed = _picture(plan, p, 0.0, index=3, ok=False)  # capture_result != 1
    rep = compute_coverage(plan, {"d1": [good, off10, off20, failed]}, planned={"pole1": 5})
    (t,) = rep.targets
    assert (t.target, t.vehicles, t.covered, t.images, t.planned) == ("pole1", ("d1",), True, 2, 5)
    # range: the camera is level with the aim point (pole1's axis at its height)
    want = math.hypot(*(c[:2] - p[:2]))
    assert t.range_m == pytest.approx((want, want), abs=1e-3)
    assert t.view_deg == pytest.approx(10.0, abs=1e-3)
    assert rep.images == 4 and rep.unmatched == 2  # off20 and the failed one
    # a gimbal pitched 12 deg below the aim point is a 12 deg view angle, too much at 10
    low = _picture(plan, p, 0.0, pitch_deg=-12.0)
    assert compute_coverage(plan, {"d1": [low]}, view_tolerance_deg=10).targets[0].images == 0
    assert compute_coverage(plan, {"d1": [low]}).targets[0].images == 1


def test_a_picture_from_outside_the_inspection_place_does_not_count_and_says_why(
    face_plan: Path,
) -> None:
    plan = load_plan(face_plan)
    p = _in_place(plan)
    region = plan.region("insp1")
    # move away from the pole until 1 m outside the place
    c = plan.region("pole1").center_enu_m
    away = np.append((p[:2] - c[:2]) / np.linalg.norm(p[:2] - c[:2]), 0.0)
    q = p.copy()
    while region.margin(q[None])[0] > -1.0:
        q = q + 0.01 * away
    rep = compute_coverage(plan, {"d1": [_picture(plan, q, 0.0)]})
    (t,) = rep.targets
    assert not t.covered and not rep.all_covered
    (line,) = [x for x in coverage_lines(rep) if "pole1" in x]
    assert "NOT covered" in line and "1.00 m outside the inspection place" in line
    # within the tolerance it counts
    near = p + (region.margin(p[None])[0] + 0.3) * away  # 0.3 m outside
    assert compute_coverage(plan, {"d1": [_picture(plan, near)]}).targets[0].covered
    # pictures by another vehicle, or none, do not cover it
    nobody = compute_coverage(plan, {})
    assert not nobody.targets[0].covered
    assert "no picture by d1" in coverage_lines(nobody)[1]


def test_the_image_log_reads_back_as_written_and_bad_logs_name_line_and_column(
    face_plan: Path, tmp_path: Path
) -> None:
    plan = load_plan(face_plan)
    ims = [_picture(plan, _in_place(plan), 3.0 * i, index=i, t_s=5.0 + i) for i in range(3)]
    path = write_images_csv(tmp_path / "images.csv", ims)
    (back,) = load_images(path).values()
    assert len(back) == 3
    for a, b in zip(ims, back, strict=True):
        assert (a.vehicle, a.index, a.ok, a.component) == (b.vehicle, b.index, b.ok, b.component)
        assert b.t_s == pytest.approx(a.t_s, abs=1e-3)
        np.testing.assert_allclose(
            b.position_enu_m(plan.origin), a.position_enu_m(plan.origin), atol=0.02
        )
        np.testing.assert_allclose(b.q_wxyz, a.q_wxyz, atol=1e-6)
    text = path.read_text().splitlines()
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join([text[0], text[1].replace(text[1].split(",")[2], "north")]) + "\n")
    with pytest.raises(InputFileError, match=r"bad.csv: line 2: column lat_deg: not a number"):
        load_images(bad)
    bad.write_text("vehicle,t_s\nd1,1\n")
    with pytest.raises(InputFileError, match=r"line 1: missing column\(s\) lat_deg"):
        load_images(bad)


def test_gcs_verify_checks_every_target_was_pictured_from_the_image_log(
    face_plan: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = load_plan(face_plan)
    good = write_images_csv(tmp_path / "good.csv", [_picture(plan, _in_place(plan))])
    assert main(["verify", str(face_plan), "--images", str(good), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    (check,) = [c for c in res["checks"] if c["name"] == "pictures of pole1"]
    assert check["ok"] and check["value"] == 1
    assert res["coverage"]["covered"] == 1
    wrong = write_images_csv(tmp_path / "wrong.csv", [_picture(plan, _in_place(plan), 40.0)])
    assert main(["verify", str(face_plan), "--images", str(wrong)]) == 1
    out = capsys.readouterr().out
    assert "FAIL pictures of pole1" in out and "view 40.0 deg > 15" in out
    # bad input: one line naming the file, exit 2
    other = write_images_csv(
        tmp_path / "other.csv", [_picture(plan, _in_place(plan), vehicle="d9")]
    )
    assert main(["verify", str(face_plan), "--images", str(other)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "other.csv: vehicle 'd9' is not in the plan" in err[0]
    assert main(["verify", str(face_plan), "--images", str(tmp_path / "none.csv")]) == 2
    assert "none.csv: cannot read" in capsys.readouterr().err


def test_the_coverage_figure_draws_each_picture_with_its_view(
    face_plan: Path, tmp_path: Path
) -> None:
    plan = load_plan(face_plan)
    p = _in_place(plan)
    ims = {"d1": [_picture(plan, p, 0.0, index=0), _picture(plan, p, 40.0, index=1)]}
    info = CameraInfo("stl-gcs", "mock", 4.5, 6.17, 4.55, (4000, 3000), 2)
    assert info.hfov_deg == pytest.approx(2 * math.degrees(math.atan(6.17 / 9.0)))
    rep = compute_coverage(plan, ims, cameras={"d1": info})
    out = coverage_figure(plan, rep, ims, tmp_path / "coverage.png")
    assert out.stat().st_size > 10_000
