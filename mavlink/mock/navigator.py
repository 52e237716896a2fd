"""PX4 navigator behaviour of the mock vehicle: mission execution, return to launch, geofence.

Mixed into :class:`mavlink.mock.vehicle.MockVehicle`; the methods use its
state (``phys``, ``index``, ``params``, ``missions``, ``home_ned_m``, ...).

Mission execution follows PX4 for multicopters: NAV items are flown one at a
time (takeoff vertically, waypoints accepted within ``param2`` or NAV_ACC_RAD
horizontally and NAV_MC_ALT_RAD vertically, then held ``param1`` s), DO items
run at once (DO_CHANGE_SPEED, DO_JUMP with repeat counts, DO_SET_HOME, camera
and gimbal items are accepted and skipped), a mission started on the ground
without a takeoff item first climbs to MIS_TAKEOFF_ALT, MISSION_ITEM_REACHED is
sent for each NAV item reached and MISSION_CURRENT on every change.  Return to
launch climbs to RTL_RETURN_ALT unless within 10 m of home (RTL_MIN_DIST),
flies home and lands.  Geofence inclusion/exclusion polygons and circles are
checked while flying; a breach triggers GF_ACTION.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock import px4
from mavlink.mock.mission import FENCE, MISSION, RALLY
from mavlink.mock.px4 import Px4Mode

_RTL_MIN_DIST_M = 10.0


class NavigatorMixin:
    """Mission, RTL and geofence logic of :class:`~mavlink.mock.vehicle.MockVehicle`."""

    def _rtl_start(self) -> None:
        i = self.index
        pos = self.phys.pos_ned_m[i]
        home = self.home_ned_m
        dist = math.hypot(pos[0] - home[0], pos[1] - home[1])
        return_d = float(home[2]) - self.params["RTL_RETURN_ALT"]
        self._rtl_alt_d_m = (
            min(float(pos[2]), return_d) if dist > _RTL_MIN_DIST_M else float(pos[2])
        )
        self._rtl_phase = "climb"
        target = pos.copy()
        target[2] = self._rtl_alt_d_m
        self.phys.set_position(i, target)

    def _rtl_tick(self) -> None:
        i = self.index
        pos = self.phys.pos_ned_m[i]
        if self._rtl_phase == "climb":
            if abs(pos[2] - self._rtl_alt_d_m) < self.params["NAV_MC_ALT_RAD"]:
                self._rtl_phase = "return"
                target = self.home_ned_m.copy()
                target[2] = self._rtl_alt_d_m
                self.phys.set_position(i, target)
                self._face(target)
        elif self._rtl_phase == "return":
            home = self.home_ned_m
            if math.hypot(pos[0] - home[0], pos[1] - home[1]) < self.params["NAV_ACC_RAD"]:
                self._rtl_phase = "land"
                self._start_descent()
                self.phys.sp_pos_ned_m[i, :2] = home[:2]

    def _face(self, target: np.ndarray) -> None:
        i = self.index
        pos = self.phys.pos_ned_m[i]
        dn, de = target[0] - pos[0], target[1] - pos[1]
        if math.hypot(dn, de) > 2.0:
            self.phys.sp_yaw_rad[i] = math.atan2(de, dn)
            self.phys.m_yaw[i] = True

    # ================================================================ mission
    def _on_plan_changed(self, mission_type: int) -> None:
        if mission_type == MISSION:
            self.mission_seq = 0
            self.mission_finished = False
            self._jump_counts.clear()
            self._mis_reached_sent = -1
            if self.mode is Px4Mode.AUTO_MISSION:
                if self.missions.plans[MISSION]:
                    self._mission_start_item(0)
                else:
                    self.set_mode(Px4Mode.AUTO_LOITER)
        elif mission_type == FENCE:
            self._build_fence()
        elif mission_type == RALLY:
            pass  # stored and served; RTL returns home (RTL_TYPE 0)

    def _mission_start_item(self, seq: int) -> None:
        """Make ``seq`` current, run DO items until the next NAV item, and head for it."""
        plan = self.missions.plans[MISSION]
        i = self.index
        for _ in range(len(plan) * 4 + 8):
            if seq >= len(plan):
                self._mission_finish()
                return
            item = plan[seq]
            cmd = item.command
            if cmd == mavlink2.MAV_CMD_DO_JUMP:
                target, repeat = int(item.param1), int(item.param2)
                done = self._jump_counts.get(seq, 0)
                if (repeat < 0 or done < repeat) and 0 <= target < len(plan):
                    self._jump_counts[seq] = done + 1
                    seq = target
                else:
                    seq += 1
                continue
            if cmd == mavlink2.MAV_CMD_DO_CHANGE_SPEED:
                if item.param2 > 0:
                    self.cruise_speed_m_s = float(item.param2)
                elif item.param2 == -1:
                    self.cruise_speed_m_s = self.params["MPC_XY_CRUISE"]
                self._apply_limits()
                seq += 1
                continue
            if cmd == mavlink2.MAV_CMD_DO_SET_HOME:
                if item.param1 >= 0.5:
                    self.home_ned_m = self.phys.pos_ned_m[i].copy()
                else:
                    self.home_ned_m = self._item_target_ned(
                        item.frame, item.x, item.y, item.z, self.home_ned_m
                    )
                seq += 1
                continue
            if cmd not in _NAV_COMMANDS:
                seq += 1  # camera, gimbal, servo ...: done at once
                continue
            break
        else:
            self._mission_finish()
            return
        changed = seq != self.mission_seq
        self.mission_seq = seq
        self._mis_hold_until_s = math.inf
        pos = self.phys.pos_ned_m[i].copy()
        if cmd == mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self.set_mode(Px4Mode.AUTO_RTL)
            self.mode = Px4Mode.AUTO_MISSION  # keep reporting mission while returning
            self._mis_phase = "rtl"
        elif cmd in (mavlink2.MAV_CMD_NAV_DELAY, mavlink2.MAV_CMD_CONDITION_DELAY):
            self.phys.hold_here(i)
            self._mis_phase = "delay"
            self._mis_hold_until_s = self._now() + max(0.0, item.param1)
        else:
            target = self._item_target_ned(item.frame, item.x, item.y, item.z, pos)
            if cmd in (mavlink2.MAV_CMD_NAV_TAKEOFF, mavlink2.MAV_CMD_NAV_VTOL_TAKEOFF):
                target[:2] = pos[:2]
                target[2] = min(target[2], pos[2])
                self._mis_phase = "takeoff"
            elif cmd in (mavlink2.MAV_CMD_NAV_LAND, mavlink2.MAV_CMD_NAV_VTOL_LAND):
                target[2] = pos[2]
                self._mis_phase = "land_approach"
            else:
                self._mis_phase = "goto"
            if self.landed and self._mis_phase == "goto":
                # PX4 takes off first when a mission starts on the ground without a takeoff
                target_to = pos.copy()
                target_to[2] = min(
                    float(self.home_ned_m[2]) - self.params["MIS_TAKEOFF_ALT"], target[2]
                )
                self._mis_target = target
                self._mis_phase = "pre_takeoff"
                self.phys.set_position(i, target_to)
            else:
                self._mis_target = target
                self.phys.set_position(i, target)
                self._face(target)
        if changed or self._mis_phase:
            self.send(self._msg_mission_current())

    def _mission_finish(self) -> None:
        plan = self.missions.plans[MISSION]
        self.mission_finished = True
        self.mission_seq = max(0, len(plan) - 1)
        self._mis_phase = "done"
        if not self.landed:
            self.phys.hold_here(self.index)
        self.send(self._msg_mission_current())

    def _item_reached(self, seq: int) -> None:
        if self._mis_reached_sent != seq:
            self._mis_reached_sent = seq
            self.send(mavlink2.MAVLink_mission_item_reached_message(seq))

    def _mission_tick(self) -> None:
        if not self.armed or self.mission_finished:
            return
        plan = self.missions.plans[MISSION]
        if self.mission_seq >= len(plan):
            return
        item = plan[self.mission_seq]
        i = self.index
        pos = self.phys.pos_ned_m[i]
        now = self._now()
        phase = self._mis_phase
        tgt = self._mis_target
        alt_rad = self.params["NAV_MC_ALT_RAD"]
        if phase == "pre_takeoff":
            if pos[2] <= self.phys.sp_pos_ned_m[i, 2] + alt_rad:
                self._mis_phase = "goto"
                self.phys.set_position(i, tgt)
                self._face(tgt)
            return
        if phase == "takeoff":
            if abs(pos[2] - tgt[2]) < alt_rad:
                self._item_reached(self.mission_seq)
                self._advance()
            return
        if phase == "goto":
            acc_rad = item.param2 if item.param2 > 0 else self.params["NAV_ACC_RAD"]
            if (
                math.hypot(pos[0] - tgt[0], pos[1] - tgt[1]) < acc_rad
                and abs(pos[2] - tgt[2]) < alt_rad
            ):
                self._item_reached(self.mission_seq)
                if math.isfinite(item.param4) and item.command == mavlink2.MAV_CMD_NAV_WAYPOINT:
                    self.phys.sp_yaw_rad[i] = math.radians(item.param4)
                if item.command == mavlink2.MAV_CMD_NAV_LOITER_UNLIM:
                    self._mis_phase = "loiter"
                    return
                hold_s = (
                    item.param1
                    if item.command
                    in (mavlink2.MAV_CMD_NAV_WAYPOINT, mavlink2.MAV_CMD_NAV_LOITER_TIME)
                    else 0.0
                )
                self._mis_hold_until_s = now + max(0.0, hold_s)
                self._mis_phase = "hold"
            return
        if phase in ("hold", "delay"):
            if now >= self._mis_hold_until_s:
                self._advance()
            return
        if phase == "land_approach":
            if math.hypot(pos[0] - tgt[0], pos[1] - tgt[1]) < self.params["NAV_ACC_RAD"]:
                self._mis_phase = "land"
                self._start_descent()
                self.phys.sp_pos_ned_m[i, :2] = tgt[:2]
            return
        if phase == "land" and self.landed:
            self._item_reached(self.mission_seq)
            self._advance()

    def _advance(self) -> None:
        self._mission_start_item(self.mission_seq + 1)

    # ================================================================ geofence
    def _build_fence(self) -> None:
        items = self.missions.plans[FENCE]
        fence: list[tuple[str, bool, np.ndarray, float]] = []
        k = 0
        while k < len(items):
            it = items[k]
            if it.command in (
                mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
            ):
                count = int(it.param1)
                verts = items[k : k + count]
                ne = np.array([self.global_to_ned(v.x / 1e7, v.y / 1e7, 0.0)[:2] for v in verts])
                inclusion = it.command == mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
                fence.append(("polygon", inclusion, ne, 0.0))
                k += max(count, 1)
                continue
            if it.command in (
                mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
                mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
            ):
                centre = self.global_to_ned(it.x / 1e7, it.y / 1e7, 0.0)[:2]
                inclusion = it.command == mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION
                fence.append(("circle", inclusion, centre, float(it.param1)))
            k += 1
        self._fence = fence
        self._fence_breached = False

    def fence_violated(self, pos_ned_m: np.ndarray) -> bool:
        """True if the local point (3,) lies outside an inclusion or inside an exclusion zone."""
        ne = pos_ned_m[:2]
        for kind, inclusion, data, radius in self._fence:
            if kind == "circle":
                inside = float(np.hypot(*(ne - data))) <= radius
            else:
                inside = _point_in_polygon(ne, data)
            if inside != inclusion:
                return True
        return False

    def _fence_tick(self) -> None:
        if not self._fence or not self.armed or self.landed:
            return
        violated = self.fence_violated(self.phys.pos_ned_m[self.index])
        if violated and not self._fence_breached:
            self._fence_breached = True
            action = int(self.params["GF_ACTION"])
            self.statustext(mavlink2.MAV_SEVERITY_CRITICAL, "Geofence violated")
            if action == 4:
                self.failsafe = True
                self._do_disarm("Flight termination: geofence")
                return
            mode = px4.GF_ACTION_MODES.get(action)
            if mode is not None:
                self.failsafe = True
                self.set_mode(mode)
        elif not violated:
            self._fence_breached = False


_NAV_COMMANDS = frozenset(
    {
        mavlink2.MAV_CMD_NAV_WAYPOINT,
        mavlink2.MAV_CMD_NAV_LOITER_UNLIM,
        mavlink2.MAV_CMD_NAV_LOITER_TURNS,
        mavlink2.MAV_CMD_NAV_LOITER_TIME,
        mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH,
        mavlink2.MAV_CMD_NAV_LAND,
        mavlink2.MAV_CMD_NAV_TAKEOFF,
        mavlink2.MAV_CMD_NAV_DELAY,
        mavlink2.MAV_CMD_NAV_VTOL_TAKEOFF,
        mavlink2.MAV_CMD_NAV_VTOL_LAND,
        mavlink2.MAV_CMD_CONDITION_DELAY,
    }
)


def _point_in_polygon(pt: np.ndarray, poly: np.ndarray) -> bool:
    """Even-odd rule for a point (2,) and polygon vertices (k, 2)."""
    x, y = float(pt[0]), float(pt[1])
    xs, ys = poly[:, 0], poly[:, 1]
    xj, yj = np.roll(xs, 1), np.roll(ys, 1)
    crosses = (ys > y) != (yj > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_int = (xj - xs) * (y - ys) / (yj - ys) + xs
    return bool(np.count_nonzero(crosses & (x < x_int)) % 2)
