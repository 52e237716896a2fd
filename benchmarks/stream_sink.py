"""A counting MAVLink sink: N minimal PX4-like endpoints in one process (for bench_stream.py).

Each endpoint ``i`` binds ``127.0.0.1:vehicle_ports[i]``, sends a HEARTBEAT
(PX4 autopilot, quad-rotor, system id ``i+1``) at 2 Hz to
``127.0.0.1:gcs_ports[i]`` (as PX4 SITL does, so MAVSDK's ``udpin://``
discovers it), acknowledges every COMMAND_LONG/COMMAND_INT as
ACCEPTED, applies MAV_CMD_DO_SET_MODE to the mode it reports, and counts
every SET_POSITION_TARGET_LOCAL_NED it receives together with the number of
*distinct* setpoints (MAVSDK re-sends the last setpoint by itself when the
stream is slower than 20 Hz; distinct positions are the GCS's own sends).

With a telemetry rate (third argument, Hz) every endpoint also sends
LOCAL_POSITION_NED at that rate: the vehicles hover on a grid 0.75 m apart, 1.5 m up
(inside the test plans' workspace, around their obstacle), so a flight's safety
monitor and progress view have real telemetry to work on. A line ``violate I J`` on stdin
puts vehicle ``I`` 5 cm from vehicle ``J`` (0-based); the sink notes when it first sent
that position and when the next command from the GCS arrived (the monitor's hold).

It has no physics: it measures the link, not a vehicle. Run as::

    python benchmarks/stream_sink.py '[GCS_PORT, ...]' '[VEHICLE_PORT, ...]' [TELEMETRY_HZ]

It prints ``ready`` once bound; on a line ``report`` on stdin it prints one
JSON line ``{"received": [...], "distinct": [...], "violated_t": T, "command_t": T}``
(``time.monotonic()`` seconds, ``null`` if none) and on ``quit`` (or end of input) it
exits.
"""

from __future__ import annotations

import json
import selectors
import socket
import struct
import sys
import threading
import time

from pymavlink.dialects.v20 import common as mav

SETPOINT_ID = mav.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED

#: The hover grid: spacing and height (m), 9 x 9 positions around the middle (which is left
#: empty: the test plans' obstacle stands there), so up to 80 vehicles.
GRID_M, SIDE, HEIGHT_M = 0.75, 9, 1.5


def grid_ned(i: int, n: int) -> tuple[float, float, float]:
    """Vehicle ``i``'s hover position (NED): the ``i``-th free grid position, row by row."""
    slots = [(r, c) for r in range(SIDE) for c in range(SIDE) if (r, c) != (SIDE // 2, SIDE // 2)]
    if not 0 <= i < len(slots) or n > len(slots):
        raise ValueError(f"the grid holds {len(slots)} vehicles, not {n}")
    r, c = slots[i]
    half = SIDE // 2
    return (r - half) * GRID_M, (c - half) * GRID_M, -HEIGHT_M


def main(argv: list[str]) -> int:
    """Run the sink until ``quit``; see the module docstring."""
    gcs_ports = [int(p) for p in json.loads(argv[1])]
    vehicle_ports = [int(p) for p in json.loads(argv[2])]
    n = len(gcs_ports)
    telemetry_hz = float(argv[3]) if len(argv) > 3 else 0.0
    pos = [list(grid_ned(i, n)) for i in range(n)]
    events: dict[str, float | None] = {"violated_t": None, "command_t": None}
    pending: list[tuple[int, int]] = []
    sel = selectors.DefaultSelector()
    socks: list[socket.socket] = []
    links: list[mav.MAVLink] = []
    modes = [0] * n
    received = [0] * n
    distinct: list[set[tuple[float, float, float]]] = [set() for _ in range(n)]
    for i in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 21)
        s.bind(("127.0.0.1", vehicle_ports[i]))
        s.setblocking(False)
        socks.append(s)
        links.append(mav.MAVLink(None, srcSystem=i + 1, srcComponent=1))
        sel.register(s, selectors.EVENT_READ, i)
    lock = threading.Lock()
    done = threading.Event()

    def commands() -> None:
        for line in sys.stdin:
            cmd = line.strip()
            if cmd == "report":
                with lock:
                    out = {"received": list(received), "distinct": [len(d) for d in distinct]}
                    out.update(events)
                print(json.dumps(out), flush=True)
            elif cmd.startswith("violate "):
                i, j = (int(x) for x in cmd.split()[1:3])
                with lock:
                    pending.append((i, j))
            elif cmd == "quit":
                break
        done.set()

    threading.Thread(target=commands, daemon=True).start()
    print("ready", flush=True)
    next_hb = 0.0
    next_pos = 0.0
    boot = time.monotonic()
    while not done.is_set():
        now = time.monotonic()
        if telemetry_hz > 0 and now >= next_pos:
            next_pos = max(next_pos + 1.0 / telemetry_hz, now)
            with lock:
                moved = list(pending)
                pending.clear()
            for i, j in moved:
                pos[i] = [pos[j][0], pos[j][1] + 0.05, pos[j][2]]
            boot_ms = int((now - boot) * 1e3)
            for i, s in enumerate(socks):
                msg = links[i].local_position_ned_encode(boot_ms, *pos[i], 0.0, 0.0, 0.0)
                s.sendto(msg.pack(links[i]), ("127.0.0.1", gcs_ports[i]))
            if moved and events["violated_t"] is None:
                events["violated_t"] = time.monotonic()
        if now >= next_hb:
            next_hb = now + 0.5
            for i, s in enumerate(socks):
                hb = links[i].heartbeat_encode(
                    mav.MAV_TYPE_QUADROTOR,
                    mav.MAV_AUTOPILOT_PX4,
                    mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_SAFETY_ARMED,
                    modes[i],
                    mav.MAV_STATE_ACTIVE,
                )
                s.sendto(hb.pack(links[i]), ("127.0.0.1", gcs_ports[i]))
        wait = 0.05 if telemetry_hz <= 0 else max(0.0, min(0.05, next_pos - time.monotonic()))
        for key, _ in sel.select(timeout=wait):
            i = key.data
            s = socks[i]
            while True:
                try:
                    data = s.recv(65536)
                except BlockingIOError:
                    break
                # Setpoints are counted from the raw MAVLink 2 frame (one per datagram from
                # MAVSDK): magic 0xFD, message id in bytes 7..9, x/y/z the payload's floats
                # 2..4. This keeps the sink cheap enough not to drop datagrams itself.
                if data[0] == 0xFD and int.from_bytes(data[7:10], "little") == SETPOINT_ID:
                    x, y, z = struct.unpack_from("<3f", data.ljust(10 + 16, b"\0"), 14)
                    with lock:
                        received[i] += 1
                        distinct[i].add((x, y, z))
                    continue
                for msg in links[i].parse_buffer(data) or ():
                    kind = msg.get_type()
                    if kind in ("COMMAND_LONG", "COMMAND_INT"):
                        if events["violated_t"] is not None and events["command_t"] is None:
                            events["command_t"] = time.monotonic()
                        if msg.command == mav.MAV_CMD_DO_SET_MODE:
                            modes[i] = (int(msg.param2) << 16) | (int(msg.param3) << 24)
                        ack = links[i].command_ack_encode(
                            msg.command,
                            mav.MAV_RESULT_ACCEPTED,
                            0,
                            0,
                            msg.get_srcSystem(),
                            msg.get_srcComponent(),
                        )
                        s.sendto(ack.pack(links[i]), ("127.0.0.1", gcs_ports[i]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv))
