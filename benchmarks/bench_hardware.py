"""Tactile frame decoding: vectorised RLE and packet parsing against a naive per-texel loop.

Frames are the DSACON32m's six matrices of the SDH-2 (6 x 14 and 6 x 13 texels, 498 in
all), RLE-coded as on the wire (dsacon32m.md, "Frame data"). Each row is measured in
the same run; the ratio column compares with the naive baseline of that row group.
"""

from __future__ import annotations

import struct
import time

import numpy as np

from touchloc.hardware import SDH2Kinematics, find_blobs
from touchloc.hardware.dsacon import PacketParser, crc16, decode_frame, decode_rle, encode_packet, encode_rle

TITLE = "Hardware: tactile frame decoding"

SHAPES = [(14, 6), (13, 6)] * 3
N = sum(a * b for a, b in SHAPES)


def naive_rle(data: bytes, n: int):
    """The obvious decoder: one Python step per unit and per texel."""
    out = []
    for i in range(0, len(data), 2):
        unit = data[i] | (data[i + 1] << 8)
        out.extend([unit & 0x0FFF] * (unit >> 12))
    if len(out) != n:
        raise ValueError("bad length")
    return out


def naive_crc(data: bytes) -> int:
    """The same CRC without a table: each table entry is recomputed bit by bit."""
    crc = 0xFFFF
    for b in data:
        t = ((crc ^ b) & 0xFF) << 8
        for _ in range(8):
            t = ((t << 1) ^ 0x1021) if t & 0x8000 else (t << 1)
        crc = (crc >> 8) ^ (t & 0xFFFF)
    return crc


def _frames(k, rng):
    out = []
    for _ in range(k):
        tex = np.zeros(N, dtype=np.int64)
        for _ in range(3):  # a few contact blobs
            i = int(rng.integers(0, N - 12))
            tex[i:i + 12] = rng.integers(200, 4096, 12)
        tex = np.minimum(tex + rng.integers(0, 3, N) * (rng.random(N) < 0.1), 4095)  # sensor noise
        out.append(tex)
    return out


def _rate(fn, items, repeat):
    t0 = time.perf_counter()
    for _ in range(repeat):
        for x in items:
            fn(x)
    return repeat * len(items) / (time.perf_counter() - t0)


def run(quick: bool) -> str:
    rng = np.random.default_rng(0)
    k, repeat = (50, 2) if quick else (200, 5)
    frames = _frames(k, rng)
    payloads = [struct.pack("<IB", i, 1) + encode_rle(f) for i, f in enumerate(frames)]
    rle = [p[5:] for p in payloads]
    packets = [encode_packet(0, p) for p in payloads]
    assert all(naive_crc(p[3:-2]) == crc16(p[3:-2]) for p in packets[:5])
    assert all(list(decode_rle(r, N)) == naive_rle(r, N) for r in rle[:5])

    rows = []
    base = _rate(lambda r: naive_rle(r, N), rle, repeat)
    rows.append(("RLE decode, naive per-texel loop", base, 1.0))
    v = _rate(lambda r: decode_rle(r, N), rle, repeat)
    rows.append(("RLE decode, numpy (`decode_rle`)", v, v / base))
    base_crc = _rate(lambda p: naive_crc(p[3:-2]), packets, repeat)
    rows.append(("CRC16 of a frame packet, bitwise loop", base_crc, 1.0))
    v = _rate(lambda p: crc16(p[3:-2]), packets, repeat)
    rows.append(("CRC16 of a frame packet, table (`crc16`)", v, v / base_crc))

    def parse(p):
        pp = PacketParser()
        pp.feed(p)
        cmd, payload = pp.next()
        return decode_frame(payload, SHAPES)

    v = _rate(parse, packets, repeat)
    rows.append(("bytes -> TactileFrame (hunt, CRC, RLE, split)", v, float("nan")))
    kin = SDH2Kinematics()
    decoded = [parse(p) for p in packets]
    angles = np.radians([45, 10, 20, 10, 20, 10, 20])
    v = _rate(lambda f: find_blobs(f, angles, kin, threshold=100), decoded, repeat)
    rows.append(("TactileFrame -> blobs -> hand-frame contacts", v, float("nan")))

    lines = ["| step | frames/s | vs naive |", "|---|---:|---:|"]
    for name, rate, ratio in rows:
        lines.append(f"| {name} | {rate:,.0f} | {'' if ratio != ratio else f'{ratio:.1f}x'} |")
    lines.append("")
    lines.append(f"{k} synthetic frames of {N} texels (3 pressure blobs each, RLE {np.mean([len(r) for r in rle]):.0f} "
                 f"bytes on average), each decoded {repeat} times. The controller streams at most a few "
                 "tens of frames per second, so every row is far above the device rate; the frame rate "
                 "of a session is set by the serial link (115200 baud: about 11 kB/s).")
    return "\n".join(lines)


if __name__ == "__main__":
    print(run(quick=True))
