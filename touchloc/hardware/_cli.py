"""``touchloc emulate`` and ``touchloc hand-info``: the hardware commands."""

from __future__ import annotations

import math
import time

import numpy as np


def register(sub):
    p = sub.add_parser("emulate", help="serve emulated SDH-2 / DSACON32m devices on a pty, TCP port or CAN bus",
                       description="Start the byte-level emulators of the SDH-2 hand and its DSACON32m tactile "
                                   "controller and print where they listen; stop with Ctrl-C. With --mesh the "
                                   "fingers stop on a mesh at a hidden pose and the pads feel it.")
    p.add_argument("--hand", choices=["tcp", "pty", "can", "none"], default="tcp",
                   help="transport of the hand emulator (default tcp)")
    p.add_argument("--tactile", choices=["tcp", "pty", "none"], default="tcp",
                   help="transport of the tactile emulator (default tcp)")
    p.add_argument("--hand-port", type=int, default=0, help="TCP port of the hand (default: a free one)")
    p.add_argument("--tactile-port", type=int, default=0, help="TCP port of the tactile controller")
    p.add_argument("--can-interface", default="socketcan",
                   help="python-can interface for --hand can (default socketcan; 'virtual' is in-process only)")
    p.add_argument("--can-channel", default="vcan0", help="CAN channel for --hand can (default vcan0)")
    from ..cli import add_mesh_argument

    add_mesh_argument(p, help_extra=" to place under the hand (e.g. cereal)")
    p.add_argument("--pose", default="0,0,0", help="hidden object pose x,y,yaw (m, m, deg) in the world")
    p.add_argument("--hand-height", type=float, default=0.18, help="hand base above the world origin, fingers down (m)")
    p.add_argument("--time-scale", type=float, default=1.0, help="emulated seconds per wall-clock second")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: Ctrl-C)")
    p.set_defaults(func=run_emulate)

    q = sub.add_parser("hand-info", help="connect to an SDH-2 (and DSACON32m) and print what they report",
                       description="Connect to a real or emulated hand and print identification, limits, "
                                   "angles, states and temperatures; with --tactile-port also the tactile "
                                   "controller's configuration and one frame's maximum.")
    q.add_argument("--port", help="pyserial URL of the hand: /dev/ttyUSB0, COM3, socket://192.168.1.42:23")
    q.add_argument("--can-interface", help="python-can interface of the hand (socketcan, pcan, ixxat, kvaser...)")
    q.add_argument("--can-channel", help="CAN channel (can0, PCAN_USBBUS1, 0...)")
    q.add_argument("--can-bitrate", type=int, default=1_000_000, help="CAN bit rate (default 1000000)")
    q.add_argument("--tactile-port", help="pyserial URL of the DSACON32m: /dev/ttyUSB1, socket://192.168.1.42:13000")
    q.add_argument("--timeout", type=float, default=1.0, help="reply timeout (s)")
    q.set_defaults(func=run_hand_info)


def _world(args):
    if not args.mesh:
        return None
    from ..cli import load_mesh
    from .emulator import SimWorld

    x, y, yaw = (float(v) for v in args.pose.split(","))
    T = np.eye(4)
    c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:2, 3] = x, y
    H = np.diag([1.0, -1.0, -1.0, 1.0])
    H[2, 3] = args.hand_height
    return SimWorld(load_mesh(args.mesh, args.scale), T, H)


def _open_bus(interface, channel, bitrate=None):
    import can

    from ..errors import DeviceDisconnected

    kw = {} if bitrate is None else {"bitrate": bitrate}
    try:
        return can.Bus(interface=interface, channel=channel, **kw)
    except (can.CanError, OSError, ImportError, ValueError) as exc:
        hint = (" (a virtual SocketCAN bus: sudo ip link add dev vcan0 type vcan && sudo ip link set up vcan0)"
                if interface == "socketcan" else "")
        raise DeviceDisconnected(f"cannot open CAN interface {interface!r} channel {channel!r}: {exc}{hint}") from exc


def _open_serial(url):
    import serial

    from ..errors import DeviceDisconnected

    try:
        return serial.serial_for_url(url, baudrate=115200, timeout=0.05)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise DeviceDisconnected(f"cannot open {url!r}: {exc}") from exc


def run_emulate(args) -> int:
    from .emulator import REST_DEG, CANServer, DSACON32mEmulator, PtyServer, SDH2Emulator, SimHand, TCPServer

    sim = SimHand(_world(args), time_scale=args.time_scale, initial_angles_deg=np.array(REST_DEG))
    servers = []
    if args.hand == "tcp":
        servers.append(("SDH-2", TCPServer(SDH2Emulator(sim), port=args.hand_port)))
    elif args.hand == "pty":
        servers.append(("SDH-2", PtyServer(SDH2Emulator(sim))))
    elif args.hand == "can":
        servers.append(("SDH-2", CANServer(SDH2Emulator(sim), bus=_open_bus(args.can_interface, args.can_channel))))
    if args.tactile == "tcp":
        servers.append(("DSACON32m", TCPServer(DSACON32mEmulator(sim), port=args.tactile_port)))
    elif args.tactile == "pty":
        servers.append(("DSACON32m", PtyServer(DSACON32mEmulator(sim))))
    for name, srv in servers:
        srv.start()
        where = (srv.url if isinstance(srv, TCPServer) else getattr(srv, "path", None)
                 or f"{args.can_interface}:{args.can_channel} (ids 42 -> 43)")
        print(f"{name} emulator on {where}", flush=True)
    try:
        end = None if args.duration is None else time.monotonic() + args.duration
        while end is None or time.monotonic() < end:
            time.sleep(0.1)
            for name, srv in servers:
                if srv.error is not None:
                    print(f"{name} emulator stopped: {srv.error}", flush=True)
                    return 1
    except KeyboardInterrupt:
        from ..cli import interruption_handled

        interruption_handled()  # the emulators stop on Ctrl-C: that is their normal end
    finally:
        for _, srv in servers:
            srv.close()
    return 0


def run_hand_info(args) -> int:
    from ..errors import ValidationError
    from .dsacon import DSACON32m
    from .sdh2 import SDH2

    if not args.port and not args.can_interface and not args.tactile_port:
        raise ValidationError("give --port URL or --can-interface/--can-channel for the hand, and/or --tactile-port")
    if args.port or args.can_interface:
        if args.can_interface:
            bus = _open_bus(args.can_interface, args.can_channel, args.can_bitrate)
            hand = SDH2.over_can(bus, timeout=args.timeout)
        else:
            hand = SDH2(_open_serial(args.port), timeout=args.timeout)
        ident = hand.identification()
        lo, hi = hand.angle_limits
        print(f"SDH-2 firmware {ident.firmware} ({ident.firmware_date}), id {ident.hand_id}, "
              f"serial {ident.serial_number}, SoC {ident.soc}, {ident.num_axes} axes")
        print("  limits (deg): " + ", ".join(f"[{a:.0f}, {b:.0f}]" for a, b in zip(np.degrees(lo), np.degrees(hi))))
        print("  angles (deg): " + ", ".join(f"{a:.2f}" for a in np.degrees(hand.actual_angles())))
        print("  states:       " + ", ".join(str(int(s)) for s in hand.state()))
        t = hand.temperatures()
        print("  temperatures: axes " + ", ".join(f"{v:.0f}" for v in t["axes"])
              + f" C, FPGA {t['fpga']:.0f} C, PCB {t['pcb']:.0f} C")
        if args.can_interface:
            bus.shutdown()
    if args.tactile_port:
        tac = DSACON32m(_open_serial(args.tactile_port), timeout=args.timeout)
        c = tac.controller
        print(f"DSACON32m serial {c.serial}, hw {c.hw_version}, sw 0x{c.sw_version:04x}, "
              f"{tac.sensor.nb_matrices} matrices")
        for i, m in enumerate(tac.matrix_infos):
            print(f"  matrix {i}: {m.cells_x} x {m.cells_y} texels of {m.texel_width:.2f} x {m.texel_height:.2f} mm")
        print(f"  one frame: max texel {tac.read_frame().max()}")
    return 0
