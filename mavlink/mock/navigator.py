"""PX4 navigator behaviour of the mock vehicle: mission execution, return to launch, geofence.

Mixed into :class:`mavlink.mock.vehicle.MockVehicle`; the methods use its
state (``phys``, ``index``, ``params``, ``missions``, ``home_ned_m``, ...).  The mission
items, what they command and what the vehicle reports about them are here; PX4's geometry
under them (the auto modes' trajectory setpoint, corner speeds, the geofence and its
braking point) is the simulation's (:mod:`mavlink.mock.sim.navigation`).

Mission execution follows PX4 for multicopters: NAV items are flown one at a
time (takeoff vertically, waypoints accepted within ``param2`` or NAV_ACC_RAD
horizontally and NAV_MC_ALT_RAD vertically, then held ``param1`` s), DO items
run at once when they become current, i.e. once the NAV item before them is completed
(DO_CHANGE_SPEED, DO_JUMP with repeat counts, DO_SET_HOME; camera, gimbal and ROI items
are issued as PX4's navigator issues them, :mod:`mavlink.mock.payload`, the mission waiting
MIS_COMMAND_TOUT after a DO_GIMBAL_MANAGER_PITCHYAW; other DO items are
skipped), with a ROI a mission faces it (PX4's ``MissionBase::heading_sp_update``,
MIS_MNT_YAW_CTL 0), a mission started on the ground
without a takeoff item first climbs to MIS_TAKEOFF_ALT, MISSION_CURRENT is sent
on every change (PX4: mostly on the next once-a-second report, ``_announce_current``).
Return to launch climbs to RTL_RETURN_ALT unless within 10 m of home (RTL_MIN_DIST),
flies home and lands.  Geofence inclusion/exclusion polygons
and circles are checked while flying; a breach triggers GF_ACTION.  A waypoint's yaw
(param4) is the heading from the moment the item is current, turned to at MPC_YAWRAUTO_MAX
(PX4's triplet yaw in ``FlightTaskAuto``); without one the vehicle heads for the waypoint.

With ``MOCK_PX4_NAV`` (the ``px4`` profile) the navigator is PX4 v1.17's
(``docs/px4-behaviour.md``, PX4's ``navigator/`` and ``FlightTaskAuto``):

* waypoints are flown along a trajectory setpoint limited by the cruise speed,
  MPC_ACC_HOR and MPC_JERK_AUTO, arriving at the corner speed
  ``min(sqrt(MPC_XY_TRAJ_P * MPC_ACC_HOR * R * tan(alpha / 2)), exit speed, cruise)``
  (0 before a hold, at the last waypoint or when the next one is within R); a
  vehicle that misses the acceptance circle (drag lag, wind) is not let go: the
  setpoint waits at the waypoint, past it if it overshot, until the vehicle's
  estimate is inside (PX4 SITL lost 18-35 s on such a waypoint at R = 0.3 m);
* MISSION_ITEM_REACHED comes when an item is *completed*: a waypoint after its
  hold (``param1``), a delay after its time, a LOITER_UNLIM never
  (``MissionBlock::is_mission_item_reached_or_completed``); it reports the last
  item processed: a DO item that
  follows a waypoint overwrites the waypoint's report before it is sent; the
  latest is re-sent about once a second, up to 10 times;
* a take-off item climbs only when the first position item is more than
  NAV_MC_ALT_RAD above the vehicle (``MissionBase::checkClimbRequired``);
  otherwise it is a waypoint, and on the ground a waypoint less than 0.2 m
  above the estimate never spins the vehicle up (auto-disarm after
  COM_DISARM_PRFLT);
* the geofence is predictive (GF_PREDICT): it fires when the braking distance
  ``v * (v / (2 MPC_ACC_HOR) + 0.6)`` ahead would cross it.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavlink.mock.mission import FENCE, MISSION, RALLY, MissionItem
from mavlink.mock.parts import VehicleParts
from mavlink.mock.payload import PAYLOAD_MISSION_COMMANDS
from mavlink.mock.sim import px4
from mavlink.mock.sim.navigation import (
    FenceZone,
    Geofence,
    braking_point,
)
from mavlink.mock.sim.px4 import Px4Mode

_RTL_MIN_DIST_M = 10.0
_REACHED_RESENDS = 10  # PX4 re-sends the last reached item up to 10 times, once a second


class NavigatorMixin(VehicleParts):
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
        elif self._rtl_phase == "land" and not self.landed:
            self.phys.sp_vel_ned_m_s[i, 2] = self._land_speed_m_s()

    def _face(self, target: np.ndarray) -> None:
        i = self.index
        pos = self.phys.pos_ned_m[i]
        dn, de = target[0] - pos[0], target[1] - pos[1]
        if math.hypot(dn, de) > 2.0:
            self.phys.sp_yaw_rad[i] = math.atan2(de, dn)
            self.phys.m_yaw[i] = True

    def _head_for(self, item: MissionItem, target: np.ndarray) -> None:
        """The heading while flying to mission item ``item``: its yaw (param4, degrees) from
        the moment it becomes current, else toward ``target``.

        PX4 (``MissionBlock::mission_item_to_position_setpoint``, ``FlightTaskAuto``): the
        current triplet's yaw is the item's, and a finite one is the yaw setpoint at once,
        turned to at most MPC_YAWRAUTO_MAX (the auto modes' yaw-rate limit here); a NaN one
        leaves the heading to MPC_YAW_MODE 0, toward the waypoint.
        """
        if item.command in _ITEM_YAW_COMMANDS and math.isfinite(item.param4):
            self.phys.sp_yaw_rad[self.index] = math.radians(item.param4)
            self.phys.m_yaw[self.index] = True
        else:
            self._face(target)

    # ================================================================ mission
    def _on_plan_changed(self, mission_type: int) -> None:
        if mission_type == MISSION:
            self.mission_seq = 0
            self.mission_finished = False
            self._jump_counts.clear()
            self._mis_reached_sent = -1
            self._seq_reached = -1
            self.traj.active = False
            self._mission_valid_s = self._now()
            # MissionBase::update_mission: a new mission starts without the old ROI (the
            # gimbal keeps pointing where it was told)
            self._roi_ned_m = None
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
                jump_to, repeat = int(item.param1), int(item.param2)
                done = self._jump_counts.get(seq, 0)
                if (repeat < 0 or done < repeat) and 0 <= jump_to < len(plan):
                    self._jump_counts[seq] = done + 1
                    seq = jump_to
                else:
                    seq += 1
                continue
            if cmd not in _NAV_COMMANDS and self.px4_nav:
                # PX4: a DO item "completes instantaneously" and becomes the reached item
                self._seq_reached = seq
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
            if cmd in PAYLOAD_MISSION_COMMANDS:
                self._mission_payload_item(item)
                wait_s = self.params["MIS_COMMAND_TOUT"]
                if cmd == mavlink2.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW and wait_s > 0.0:
                    # PX4 waits MIS_COMMAND_TOUT here for the gimbal to turn
                    # (MissionBlock::item_has_timeout), holding the last setpoint
                    changed = seq != self.mission_seq
                    self.mission_seq = seq
                    self._mis_phase = "hold"
                    self._mis_hold_until_s = self._now() + wait_s
                    if changed:
                        self._announce_current()
                    return
                seq += 1
                continue
            if cmd not in _NAV_COMMANDS:
                seq += 1  # servo, other camera items ...: done at once
                continue
            break
        else:
            self._mission_finish()
            return
        changed = seq != self.mission_seq
        self.mission_seq = seq
        self._mis_hold_until_s = math.inf
        if cmd not in (mavlink2.MAV_CMD_NAV_WAYPOINT, mavlink2.MAV_CMD_NAV_LOITER_TIME,
                       mavlink2.MAV_CMD_NAV_LOITER_UNLIM, mavlink2.MAV_CMD_NAV_TAKEOFF,
                       mavlink2.MAV_CMD_NAV_VTOL_TAKEOFF, mavlink2.MAV_CMD_NAV_LAND,
                       mavlink2.MAV_CMD_NAV_VTOL_LAND):  # fmt: skip
            self.traj.active = False
        pos = self.phys.pos_ned_m[i].copy()
        if cmd == mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            # PX4 v1.17 (seen on SITL): the return item is reached at once, the mission is
            # complete (MISSION_CURRENT on it, MISSION_STATE_COMPLETE) and the vehicle flies
            # home and lands in AUTO.RTL, which it reports
            self._item_reached(seq)
            self._mission_finish(then=Px4Mode.AUTO_RTL)
            return
        elif cmd in (mavlink2.MAV_CMD_NAV_DELAY, mavlink2.MAV_CMD_CONDITION_DELAY):
            self.phys.hold_here(i)
            self._mis_phase = "delay"
            self._mis_hold_until_s = self._now() + max(0.0, item.param1)
        else:
            target = self._item_target_ned(item.frame, item.x, item.y, item.z, pos)
            alt_rad = self.params["NAV_MC_ALT_RAD"]
            if cmd in (mavlink2.MAV_CMD_NAV_TAKEOFF, mavlink2.MAV_CMD_NAV_VTOL_TAKEOFF) and (
                self.px4_nav and pos[2] - target[2] <= alt_rad
            ):
                # PX4 climbs only when the item is more than NAV_MC_ALT_RAD above the
                # vehicle; otherwise the take-off is flown as a waypoint (below: never a
                # climb first, since it is within NAV_MC_ALT_RAD)
                target[:2] = pos[:2]
                self._mis_phase = "goto"
            elif cmd in (mavlink2.MAV_CMD_NAV_TAKEOFF, mavlink2.MAV_CMD_NAV_VTOL_TAKEOFF):
                target[:2] = pos[:2]
                target[2] = min(target[2], pos[2])
                self._mis_phase = "takeoff"
                self.traj.active = False
            elif cmd in (mavlink2.MAV_CMD_NAV_LAND, mavlink2.MAV_CMD_NAV_VTOL_LAND):
                # PX4 v1.17 (Mission::do_need_move_to_land, rotary wing): farther than the
                # acceptance radius from the land point it first flies there at its altitude
                # as a waypoint, reported reached on arrival; then it descends at the land
                # speed while it closes the last metres (seen on SITL: level to 1.7 m short,
                # "reached", then down at 1.5 m/s graded to 0.7 m/s)
                target[2] = pos[2]
                self._mis_phase = "land_approach"
                self._mis_land_moved = (
                    math.hypot(pos[0] - target[0], pos[1] - target[1]) >= self.params["NAV_ACC_RAD"]
                )
            else:
                self._mis_phase = "goto"
            climb = not self.px4_nav or pos[2] - target[2] > alt_rad
            if self.landed and self._mis_phase == "goto" and climb:
                # PX4 takes off first when a mission starts on the ground without a takeoff
                target_to = pos.copy()
                target_to[2] = min(
                    float(self.home_ned_m[2]) - self.params["MIS_TAKEOFF_ALT"], target[2]
                )
                self._mis_target = target
                self._mis_phase = "pre_takeoff"
                self.traj.active = False
                self.phys.set_position(i, target_to)
            else:
                # PX4's previous triplet waypoint: the last target, or here on a first leg
                prev = self._mis_target.copy() if self.traj.active else pos.copy()
                self._mis_target = target
                self.phys.set_position(i, target)
                self._head_for(item, target)
                if self._mis_phase in ("goto", "land_approach"):
                    self._traj_begin(target, prev)
        if changed or self._mis_phase:
            self._announce_current()

    def _mission_finish(self, then: Px4Mode | None = None) -> None:
        """The mission is complete: hold where it ends (or ``then``: AUTO.RTL at a return
        item)."""
        self.traj.active = False
        plan = self.missions.plans[MISSION]
        self.mission_finished = True
        self.mission_seq = max(0, len(plan) - 1)
        self._mis_phase = "done"
        if then is not None and self.mode is Px4Mode.AUTO_MISSION:
            self.set_mode(then)
        elif not self.landed:
            self.phys.hold_here(self.index)
            if self.px4_nav and self.mode is Px4Mode.AUTO_MISSION:
                # PX4 v1.17 holds where a mission ends in the air (seen on SITL: AUTO.LOITER
                # within the second, before MAVSDK reports the mission finished)
                self.set_mode(Px4Mode.AUTO_LOITER)
        self._announce_current()

    def _announce_current(self, *, set_by_client: bool = False) -> None:
        """MISSION_CURRENT after the current item changed, as PX4 v1.17 sends it on one link.

        PX4's ``MavlinkMissionManager`` keeps the current seq in a *static* shared by all
        its MAVLink instances (GCS, API/offboard, onboard) and sends MISSION_CURRENT only
        when its copy differs from the navigator's: whichever instance runs first sends
        it, the others see no change and report it on their once-a-second stream.  On the
        API link PX4 SITL sent 4 of 65 advances at once, the rest 0.1-0.9 s later
        (``MOCK_MC_NOW``, the chance of at once); a MISSION_SET_CURRENT sets the static
        itself, so its change is never sent at once.  MISSION_ITEM_REACHED is
        per-instance and always prompt.  The ideal vehicle sends every change at once.
        """
        at_once = not self.px4_nav or (
            not set_by_client and self._mc_rng.random() < self.params["MOCK_MC_NOW"]
        )
        if at_once:
            self.send(self._msg_mission_current())

    def _item_reached(self, seq: int) -> None:
        if self.px4_nav:
            self._seq_reached = seq  # sent at the end of the tick (reached_tick)
        elif self._mis_reached_sent != seq:
            self._mis_reached_sent = seq
            self.send(mavlink2.MAVLink_mission_item_reached_message(seq))

    def _reached_tick(self, now: float) -> None:
        """MISSION_ITEM_REACHED as PX4's mavlink_mission.cpp: on change, then once a second
        up to 10 times (only the last processed item: see the module docstring)."""
        seq = self._seq_reached
        if seq < 0:
            return
        if seq != self._mis_reached_sent:
            self._mis_reached_sent = seq
            self._reached_resends = 0
        elif self._reached_resends >= _REACHED_RESENDS or now < self._reached_next_s:
            return
        else:
            self._reached_resends += 1
        self._reached_next_s = now + 1.0
        self.send(mavlink2.MAVLink_mission_item_reached_message(seq))

    # ---------------------------------------------------------------- PX4 trajectory
    def _traj_begin(self, target: np.ndarray, prev: np.ndarray) -> None:
        """Start the leg ``prev`` -> ``target`` of the current item (PX4 nav only)."""
        if not self.px4_nav:
            return
        item = self.missions.plans[MISSION][self.mission_seq]
        radius = item.param2 if item.param2 > 0 else self.params["NAV_ACC_RAD"]
        hold = item.command == mavlink2.MAV_CMD_NAV_WAYPOINT and item.param1 > 0
        nxt = None if hold else self._next_position(self.mission_seq)
        self.traj.begin(
            self.phys.pos_ned_m[self.index], target, prev, nxt, radius, self.params,
            self.cruise_speed_m_s,
        )  # fmt: skip

    def _next_position(self, seq: int) -> np.ndarray | None:
        """Local position of the next waypoint-like item after ``seq`` (DO items skipped)."""
        plan = self.missions.plans[MISSION]
        for it in plan[seq + 1 :]:
            if it.command in _NAV_COMMANDS:
                if it.command in (
                    mavlink2.MAV_CMD_NAV_WAYPOINT,
                    mavlink2.MAV_CMD_NAV_LOITER_TIME,
                    mavlink2.MAV_CMD_NAV_LOITER_UNLIM,
                ):
                    return self._item_target_ned(it.frame, it.x, it.y, it.z, self._mis_target)
                return None
            if it.command == mavlink2.MAV_CMD_DO_JUMP:
                return None
        return None

    def _traj_step(self, target: np.ndarray) -> None:
        """Advance PX4's trajectory setpoint one step toward ``target`` and command it
        (:meth:`AutoTrajectory.step`)."""
        i = self.index
        pos, vel, acc = self.traj.step(
            self.phys.pos_ned_m[i], target, self.fleet.dt_s, self.params, self.cruise_speed_m_s
        )
        self.phys.set_position(i, pos, vel, acc)

    def _mission_tick(self) -> None:
        self._mission_step()
        if self._roi_ned_m is not None and self.mode is Px4Mode.AUTO_MISSION:
            self._roi_heading()

    def _roi_heading(self) -> None:
        """Face the ROI while flying a mission (``MissionBase::heading_sp_update``).

        PX4 (MIS_MNT_YAW_CTL 0, a multicopter) turns the current setpoint's yaw toward the ROI
        every cycle, except on take-off and landing items and while within the acceptance
        radius (NAV_ACC_RAD) of it horizontally.
        """
        if self.params["MIS_MNT_YAW_CTL"] >= 0.5 or not self.armed or self.mission_finished:
            return
        if self._mis_phase not in ("goto", "hold", "delay", "loiter"):
            return
        plan = self.missions.plans[MISSION]
        if not (0 <= self.mission_seq < len(plan)) or plan[self.mission_seq].command in (
            mavlink2.MAV_CMD_NAV_TAKEOFF, mavlink2.MAV_CMD_NAV_VTOL_TAKEOFF,
            mavlink2.MAV_CMD_NAV_LAND, mavlink2.MAV_CMD_NAV_VTOL_LAND,
        ):  # fmt: skip
            return
        roi = self._roi_ned_m
        assert roi is not None
        i = self.index
        pos = self.phys.pos_ned_m[i]
        dn, de = float(roi[0] - pos[0]), float(roi[1] - pos[1])
        if math.hypot(dn, de) > self.params["NAV_ACC_RAD"]:
            self.phys.sp_yaw_rad[i] = math.atan2(de, dn)
            self.phys.m_yaw[i] = True

    def _mission_step(self) -> None:
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
                self._head_for(item, tgt)
            return
        if phase == "takeoff":
            if abs(pos[2] - tgt[2]) < alt_rad:
                self._item_reached(self.mission_seq)
                self._advance()
            return
        if phase == "goto":
            if self.traj.active:
                self._traj_step(tgt)
            acc_rad = item.param2 if item.param2 > 0 else self.params["NAV_ACC_RAD"]
            if (
                math.hypot(pos[0] - tgt[0], pos[1] - tgt[1]) < acc_rad
                and abs(pos[2] - tgt[2]) < alt_rad
            ):
                if not self.px4_nav:
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
                if self.px4_nav and hold_s <= 0.0:
                    # PX4 moves on in the same cycle: a following DO item is processed (and
                    # becomes the reached item) before MAVLink sends the waypoint's report
                    self._item_reached(self.mission_seq)
                    self._advance()
            return
        if phase in ("hold", "delay", "loiter"):
            if self.traj.active and phase != "delay":
                self._traj_step(tgt)  # brake to the waypoint
            if phase != "loiter" and now >= self._mis_hold_until_s:
                if self.px4_nav:
                    # PX4 reports an item reached once its time inside (hold, delay) is over
                    # (MissionBlock::is_mission_item_reached_or_completed)
                    self._item_reached(self.mission_seq)
                self._advance()
            return
        if phase == "land_approach":
            if self.traj.active:
                self._traj_step(tgt)
            if math.hypot(pos[0] - tgt[0], pos[1] - tgt[1]) < self.params["NAV_ACC_RAD"]:
                if self.px4_nav and self._mis_land_moved:
                    self._item_reached(self.mission_seq)  # the move-to-land waypoint
                self._mis_phase = "land"
                self._start_descent()
                self.phys.sp_pos_ned_m[i, :2] = tgt[:2]
                self._land_tick()
            return
        if phase == "land":
            if self.landed:
                self._item_reached(self.mission_seq)  # PX4: nothing new after a move-to-land
                self._advance()
            else:
                self._land_tick()

    def _land_tick(self) -> None:
        """A mission land: the horizontal trajectory closing the last metres to the land
        position (PX4) and the descent at PX4's land speed."""
        i = self.index
        phys = self.phys
        if self.traj.active:
            # the land setpoint has no altitude (NaN in PX4): the leg and the setpoint are
            # kept at the vehicle's height, so the trajectory's geometry is horizontal
            down = float(phys.pos_ned_m[i, 2])
            self._mis_target[2] = down
            self.traj.hold_height(down)
            self._traj_step(self._mis_target)
        phys.m_pos[i, 2] = 0.0
        phys.m_acc[i, 2] = 0.0
        phys.m_vel[i, 2] = 1.0
        phys.sp_vel_ned_m_s[i, 2] = self._land_speed_m_s()

    def _advance(self) -> None:
        self._mission_start_item(self.mission_seq + 1)

    # ================================================================ geofence
    def _build_fence(self) -> None:
        items = self.missions.plans[FENCE]
        fence: list[FenceZone] = []
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
        self._fence = Geofence(fence)
        self._fence_breached = False

    def fence_violated(self, pos_ned_m: np.ndarray) -> bool:
        """True if the local point (3,) lies outside an inclusion or inside an exclusion zone."""
        return self._fence.violated(pos_ned_m)

    def predicted_stop_ned_m(self) -> np.ndarray:
        """Where PX4's geofence expects the vehicle to stop (:func:`braking_point`, on the
        estimate)."""
        i = self.index
        return braking_point(
            self.phys.pos_ned_m[i], self.phys.vel_ned_m_s[i], self.params["MPC_ACC_HOR"]
        )

    def _fence_tick(self) -> None:
        if not self._fence or not self.armed or self.landed:
            return
        pos = self.phys.pos_ned_m[self.index]
        predict = self.params["GF_PREDICT"] >= 0.5
        violated = self.fence_violated(pos) or (
            predict and self.fence_violated(self.predicted_stop_ned_m())
        )
        if violated and not self._fence_breached:
            self._fence_breached = True
            action = int(self.params["GF_ACTION"])
            if predict:
                self.statustext(
                    mavlink2.MAV_SEVERITY_CRITICAL, "Geofence: approaching or outside geofence"
                )
            else:
                self.statustext(mavlink2.MAV_SEVERITY_CRITICAL, "Geofence violated")
            if action == 4:
                self.failsafe = True
                self._do_disarm("Flight termination: geofence")
                return
            mode = px4.GF_ACTION_MODES.get(action)
            if mode is not None:
                self.failsafe = True
                if predict:
                    self.statustext(mavlink2.MAV_SEVERITY_CRITICAL, "Failsafe activated")
                self.set_mode(mode)
        elif not violated:
            self._fence_breached = False


#: Mission items whose param4 is the heading to fly them with (PX4's ``mission_item.yaw``).
_ITEM_YAW_COMMANDS = frozenset(
    {
        mavlink2.MAV_CMD_NAV_WAYPOINT,
        mavlink2.MAV_CMD_NAV_LOITER_TIME,
        mavlink2.MAV_CMD_NAV_LOITER_UNLIM,
    }
)

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
