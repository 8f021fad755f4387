"""Localise an object with guarded touches of the SDH-2, end to end.

By default everything runs against the emulators: the SDH-2 emulator on python-can's
virtual CAN bus (requests on id 42, answers on id 43), the DSACON32m emulator on a pty
pair, and a simulated world in which a bundled mesh sits at a hidden pose under the hand.
A fixed sequence of touches (thumb and both fingers, several base angles and heights) is
executed with the guarded-touch executor; every touch is appended to a session log; the
contacts go to an estimator (Scaling Series over x, y, yaw) and the recovered pose is
compared with the hidden one.

Run::

    python examples/hardware_localize.py                 # emulated, virtual CAN
    python examples/hardware_localize.py --mesh milk --seed 3

On a real hand (see docs/hardware.md), the same code runs with the real transports::

    python examples/hardware_localize.py --can-interface socketcan --can-channel can0 \\
        --tactile-port /dev/ttyUSB0 --hand-height 0.15
    # PEAK: --can-interface pcan --can-channel PCAN_USBBUS1; IXXAT: --can-interface ixxat --can-channel 0
    # RS232 hand instead of CAN: --hand-port /dev/ttyUSB1; Ethernet: --hand-port socket://192.168.1.42:23
    #   and --tactile-port socket://192.168.1.42:13000

The hand must be mounted fingers down, ``--hand-height`` metres above the table, with the
object roughly under its palm; nothing else may be within reach of the fingers.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from touchloc import geometry
from touchloc.data import load_object
from touchloc.hardware import DSACON32m, GuardedTouchExecutor, SDH2, read_session, replay, session_contacts
from touchloc.hardware.emulator import EmulatedRig, SimWorld
from touchloc.models import ProximityModel


def hand_pose(height: float) -> np.ndarray:
    """T_world_hand of a hand mounted fingers down ``height`` m above the world origin."""
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # hand z points down, hand y flipped
    T[2, 3] = height
    return T


def touch_sequence(ex: GuardedTouchExecutor):
    """A fixed set of horizontal touches: the thumb, and fingers 0 and 2 at six base angles.

    Each line lies in a finger plane, 0.112 m below the proximal joints (where the distal
    pads are close to vertical), from 30 mm outside the joint to 40 mm inside. Base angles
    from 0 to 90 deg make fingers 0 and 2 approach from directions spread over half a turn
    on each side, so that a long object meets some touch on every face.
    """
    z = 0.112
    touches = [ex.finger_touch(1, 0.0, (-0.03, z), (0.04, z), name="thumb")]
    for a0 in (90.0, 72.0, 54.0, 36.0, 18.0, 0.0):
        for f in (0, 2):
            touches.append(ex.finger_touch(f, math.radians(a0), (-0.03, z), (0.04, z),
                                           name=f"finger {f} a0={a0:.0f}"))
    return touches


def estimate(obj, log_path, *, seed: int, half_extent: float, restarts: int = 3):
    """Pose estimate from a session log, by Scaling Series over x, y and yaw on the table."""
    from touchloc.belief import PoseRegion, ScalingSeries

    model = ProximityModel(obj, sigma_pos=0.003, sigma_nor=0.5)
    region = PoseRegion.planar(center=(0.0, 0.0), half_extent=half_extent, z=0.0)
    # a few independent runs, keeping the most likely answer: with a dozen contacts one run
    # now and then settles in a worse mode
    contacts = session_contacts(log_path)
    best, best_ll = None, -np.inf
    for k in range(restarts):
        pose = replay(log_path, ScalingSeries(model, rng=seed + 1000 * k, progress=False), region).map_pose()
        ll = float(model.log_likelihood(pose[None], contacts)[0])
        if ll > best_ll:
            best, best_ll = pose, ll
    return best, f"Scaling Series (best of {restarts} runs)"


def show(res) -> None:
    what = f"{len(res.contact)} contact(s)" if res.hit else "free"
    print(f"  {res.touch.name:28s} travel {res.travel * 1e3:5.1f} mm  {what}")


def run_planned(ex, obj, true, args) -> None:
    """Active localisation: the planner picks each touch from the fixed set, given the belief."""
    from touchloc.belief import PoseRegion
    from touchloc.hardware import HandWorld
    from touchloc.planners import OneStepPlanner
    from touchloc.planners.loop import active_localization

    model = ProximityModel(obj, sigma_pos=0.003, sigma_nor=0.5)
    region = PoseRegion.planar(center=(0.0, 0.0), half_extent=0.03, z=0.0)
    result = active_localization(HandWorld(ex, true), model, region, OneStepPlanner(model),
                                 touch_sequence(ex), max_touches=args.max_touches, min_touches=6, rng=args.seed,
                                 callback=lambda step: [show(r) for r in step.results])
    print(f"planner stopped after {result.touches} touches (confident: {result.confident})")


def yaw_error(Ta, Tb, symmetry: int) -> float:
    """Yaw difference (deg) modulo the object's symmetry order about z."""
    d = math.atan2(Ta[1, 0], Ta[0, 0]) - math.atan2(Tb[1, 0], Tb[0, 0])
    period = 2 * math.pi / symmetry
    return math.degrees(abs((d + period / 2) % period - period / 2))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mesh", default="cereal", help="bundled mesh of the emulated world (default cereal)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--hand-height", type=float, default=0.18, help="hand base above the table origin (m)")
    ap.add_argument("--time-scale", type=float, default=4.0, help="emulated seconds per wall second")
    ap.add_argument("--log", default=None, help="session log path (default: a temporary file)")
    ap.add_argument("--planned", action="store_true",
                    help="choose each touch with the one-step planner (expected entropy) instead of the fixed order")
    ap.add_argument("--max-touches", type=int, default=10, help="with --planned: most touches")
    ap.add_argument("--velocity", action="store_true",
                    help="velocity-controlled touches (con=1, tvav) instead of 2 mm position steps")
    ap.add_argument("--can-interface", help="real hand on CAN: python-can interface (socketcan, pcan, ixxat...)")
    ap.add_argument("--can-channel", help="real hand on CAN: channel (can0, PCAN_USBBUS1, 0...)")
    ap.add_argument("--can-bitrate", type=int, default=1_000_000)
    ap.add_argument("--hand-port", help="real hand on RS232/Ethernet: pyserial URL (/dev/ttyUSB1, socket://...)")
    ap.add_argument("--tactile-port", help="real DSACON32m: pyserial URL (/dev/ttyUSB0, socket://...:13000)")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore", UserWarning)

    obj = load_object(args.mesh)
    T_hand = hand_pose(args.hand_height)
    log_path = Path(args.log) if args.log else Path(tempfile.mkdtemp()) / "session.jsonl"
    real = bool(args.tactile_port)
    rig = None
    if real:
        import serial

        if args.can_interface:
            import can

            hand = SDH2.over_can(can.Bus(interface=args.can_interface, channel=args.can_channel,
                                         bitrate=args.can_bitrate))
        else:
            hand = SDH2(serial.serial_for_url(args.hand_port, baudrate=115200, timeout=0.05))
        tactile = DSACON32m(serial.serial_for_url(args.tactile_port, baudrate=115200, timeout=0.05))
        true = None
    else:
        rng = np.random.default_rng(args.seed)
        true = geometry.vector_to_pose([[*rng.uniform(-0.01, 0.01, 2), 0.0, 0.0, 0.0,
                                         rng.uniform(-np.pi, np.pi)]])[0]
        rig = EmulatedRig(SimWorld(obj, true, T_hand), hand_transport="can", tactile_transport="pty",
                          time_scale=args.time_scale).start()
        hand = rig.open_hand()
        tactile = rig.open_tactile()
        print(f"emulated SDH-2 on CAN {rig.hand_address}, DSACON32m on {rig.tactile_address}")
    try:
        print(f"hand firmware {hand.firmware_version()}, tactile matrices {tactile.shapes}")
        ex = GuardedTouchExecutor(hand, tactile, hand_pose=T_hand, log=log_path,
                                  mode="velocity" if args.velocity else "steps")
        t0 = time.perf_counter()
        if args.planned:
            run_planned(ex, obj, true, args)
        else:
            for touch in touch_sequence(ex):
                show(ex.execute(touch))
        print(f"{ex.log.count} touches in {time.perf_counter() - t0:.1f} s, logged to {log_path}")
    finally:
        if rig is not None:
            rig.close()

    # replay the session from disk into the estimator, as after a crash
    recs = read_session(log_path)
    contacts = session_contacts(recs)
    print(f"{len(contacts)} contacts from {sum(r.result.hit for r in recs)} touches")
    t0 = time.perf_counter()
    est, how = estimate(obj, log_path, seed=args.seed, half_extent=0.03)
    print(f"{how}: {time.perf_counter() - t0:.1f} s")
    yaw = math.degrees(math.atan2(est[1, 0], est[0, 0]))
    print(f"estimate: x={est[0, 3] * 1e3:.1f} mm y={est[1, 3] * 1e3:.1f} mm yaw={yaw:.1f} deg")
    if true is not None:
        err_t = np.linalg.norm(est[:2, 3] - true[:2, 3]) * 1e3
        sym = 2 if args.mesh in ("bread", "cereal") else (4 if args.mesh == "milk" else 1)
        err_y = yaw_error(est, true, sym)
        print(f"hidden:   x={true[0, 3] * 1e3:.1f} mm y={true[1, 3] * 1e3:.1f} mm "
              f"yaw={math.degrees(math.atan2(true[1, 0], true[0, 0])):.1f} deg")
        print(f"error: {err_t:.1f} mm, {err_y:.1f} deg (yaw modulo the {sym}-fold symmetry)")
        return 0 if err_t < 5.0 and err_y < 10.0 else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
