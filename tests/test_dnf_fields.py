"""Dynamic neural fields (seed 000, eq. 1 and eq. 2): peaks, self-sustainment, periodicity,
memory trace rates, 2-D field and projections."""

import numpy as np
import pytest

from touchloc.dnf import (Field1D, Field2D, FieldParams, MemoryTrace, diagonal_sum, expand, lateral_inputs,
                          lateral_kernel, sigmoid)
from touchloc.dnf.fields import circular_convolve, site_angles
from touchloc.errors import ValidationError

N = 360
DEG = np.pi / 180

# input-driven: a peak needs input (kernel too weak to hold it alone)
DRIVEN = FieldParams(tau=2.0, h=-5.0, beta=4.0, c_exc=0.5, sigma_exc=3 * DEG, c_inh=0.15, sigma_inh=12 * DEG)
# self-sustaining: strong local excitation, surround and global inhibition (working memory)
SUSTAINED = FieldParams(tau=2.0, h=-5.0, beta=4.0, c_exc=2.5, sigma_exc=3 * DEG, c_inh=0.5, sigma_inh=15 * DEG,
                        c_glob=0.02)


def bump(center_deg, amp=7.0, width_deg=4.0):
    d = (site_angles(N) - center_deg * DEG + np.pi) % (2 * np.pi) - np.pi
    return amp * np.exp(-0.5 * (d / (width_deg * DEG)) ** 2)


def active_sites(f, thr=0.5):
    return np.flatnonzero(f > thr)


def n_peaks(f, thr=0.5):
    """Number of connected runs of active sites on the ring."""
    a = (f > thr).astype(int)
    return int(np.sum((a == 1) & (np.roll(a, 1) == 0)))


@pytest.mark.parametrize("params", [DRIVEN, SUSTAINED], ids=["driven", "sustained"])
def test_single_input_makes_one_stable_peak_at_the_input(params):
    field = Field1D(N, params)
    S = bump(100.0)
    for _ in range(60):
        f = field.step(S)
    assert n_peaks(f) == 1
    pos = np.degrees(field.peak_position())
    assert abs(pos - 100.0) < 1.0          # symmetric input: centred within one site
    for _ in range(60):
        g = field.step(S)
    assert np.max(np.abs(g - f)) < 1e-3     # stable: settled to a fixed point
    assert np.all(f[(np.abs(site_angles(N) / DEG - 100.0) > 20)] < 0.01)   # nothing elsewhere


def test_peak_survives_removal_of_input_only_when_self_sustaining():
    driven, sustained = Field1D(N, DRIVEN), Field1D(N, SUSTAINED)
    S = bump(200.0)
    for _ in range(40):
        driven.step(S)
        sustained.step(S)
    assert n_peaks(driven.output()) == 1 and n_peaks(sustained.output()) == 1
    for _ in range(100):
        fd = driven.step(0.0)
        fs = sustained.step(0.0)
    assert fd.max() < 0.01                              # input-driven peak decays to rest
    assert n_peaks(fs) == 1                             # self-sustained peak persists ...
    assert abs(np.degrees(sustained.peak_position()) - 200.0) < 1.0   # ... where it was


def test_no_peak_without_input_and_weak_input_stays_subthreshold():
    field = Field1D(N, DRIVEN)
    for _ in range(50):
        f = field.step(bump(50.0, amp=2.0))
    assert f.max() < 0.1
    np.testing.assert_allclose(field.u.min(), DRIVEN.h, atol=0.5)


def test_periodic_boundary_peak_at_359_interacts_with_1_degree():
    # the kernel weight between 359 deg and 1 deg is that of a 2 deg distance
    k = lateral_kernel(N, DRIVEN)
    f = np.zeros(N)
    f[359] = 1.0
    lat = circular_convolve(f, np.fft.rfft(k), N)
    assert lat[1] == pytest.approx(k[2]) and lat[1] == pytest.approx(lat[357])
    # two inputs at 359 and 1 deg merge across the boundary into one peak centred at 0
    field = Field1D(N, SUSTAINED)
    for _ in range(60):
        f = field.step(bump(359.0, amp=4.0) + bump(1.0, amp=4.0))
    assert n_peaks(f) == 1
    pos = np.degrees(field.peak_position())
    assert min(pos, 360 - pos) < 0.5
    assert f[0] > 0.9 and f[359] > 0.9 and f[1] > 0.9


def test_fft_convolution_equals_direct_periodic_sum(rng):
    k = lateral_kernel(N, DRIVEN.with_(c_glob=0.01))
    f = rng.random(N)
    direct = np.array([sum(f[j] * k[(i - j) % N] for j in range(N)) for i in range(0, N, 37)])
    np.testing.assert_allclose(circular_convolve(f, np.fft.rfft(k), N)[::37], direct, rtol=1e-9, atol=1e-9)


def test_memory_trace_builds_where_output_is_high_and_decays_elsewhere_at_stated_rates():
    mt = MemoryTrace(4, tau=2.0, build=0.2, decay=0.01, dt=1.0)
    f = np.array([1.0, 0.0, 1.0, 0.0])
    for _ in range(10):
        P = mt.step(f).copy()
    # f = 1: tau dP = build (1 - P) -> P_k = 1 - (1 - dt build / tau)^k
    assert P[0] == pytest.approx(1 - (1 - 0.2 / 2) ** 10)
    assert P[1] == 0.0
    mt.P[:] = 0.8
    for _ in range(20):
        P = mt.step(f).copy()
    # f = 0: tau dP = -decay P -> P_k = P0 (1 - dt decay / tau)^k
    assert P[1] == pytest.approx(0.8 * (1 - 0.01 / 2) ** 20)
    assert P[0] > 0.8                                  # still building where output is high
    # f = 1 drives P towards f, never above it
    for _ in range(500):
        P = mt.step(f)
    assert P.max() <= 1.0 and P[0] == pytest.approx(1.0, abs=1e-6)


def test_memory_trace_decay_scale_scales_the_forgetting_per_site():
    """A per-site decay scale multiplies only the decay: 0 holds a site, 2 doubles its rate,
    1 (or none) is the plain step; a scale of the wrong shape is refused."""
    mt, plain = MemoryTrace(3, tau=2.0, decay=0.01), MemoryTrace(3, tau=2.0, decay=0.01)
    mt.P[:] = plain.P[:] = 0.8
    f = np.zeros(3)
    for _ in range(20):
        P = mt.step(f, decay_scale=np.array([0.0, 2.0, 1.0])).copy()
        Q = plain.step(f).copy()
    assert P[0] == 0.8 and P[1] == pytest.approx(0.8 * (1 - 2 * 0.01 / 2) ** 20) and P[2] == Q[2]
    assert MemoryTrace(3).step(np.ones(3), decay_scale=0.5).tolist() == MemoryTrace(3).step(np.ones(3)).tolist()
    with pytest.raises(ValidationError, match="decay_scale"):
        mt.step(f, decay_scale=np.ones(4))
    with pytest.raises(ValidationError):
        mt.step(f, decay_scale="fast")


def test_memory_trace_rejects_unstable_step():
    with pytest.raises(ValidationError, match="stable Euler"):
        MemoryTrace(10, tau=1.0, build=3.0)


def test_sigmoid_is_bounded_without_overflow():
    u = np.array([-1e6, -10.0, 0.0, 10.0, 1e6])
    f = sigmoid(u, 4.0)
    assert f[0] == 0.0 and f[-1] == 1.0 and f[2] == 0.5
    np.testing.assert_allclose(f[1:4], 1 / (1 + np.exp(-4 * u[1:4])), rtol=1e-12, atol=1e-15)
    assert sigmoid(np.float32([1e30]), 4.0).dtype == np.float32


def test_expand_and_diagonal_sum_encode_one_dimension_relative_to_the_other():
    a = np.zeros(N)
    b = np.zeros(N)
    a[350], b[10] = 1.0, 1.0
    F = expand(a, N, axis=0) * expand(b, N, axis=1)       # single site at (350, 10)
    assert F.shape == (N, N) and F[350, 10] == 1.0 and F.sum() == 1.0
    d = diagonal_sum(F)
    assert np.argmax(d) == 20                              # 10 - 350 = 20 (mod 360)
    G = np.random.default_rng(3).random((7, 7))
    ref = np.array([sum(G[i, (i + k) % 7] for i in range(7)) for k in range(7)])
    np.testing.assert_allclose(diagonal_sum(G), ref)
    with pytest.raises(ValidationError, match="square"):
        diagonal_sum(np.zeros((3, 4)))


def test_field2d_peak_at_coincidence_of_two_ridges_and_active_method_matches_fft():
    p = FieldParams(tau=1.0, h=-8.0, beta=4.0, c_exc=0.3, sigma_exc=2 * DEG, c_glob=0.0005)
    A = (4.5 * (bump(30.0, amp=1.0) > 0.5)).astype(np.float32)
    B = (4.5 * (bump(300.0, amp=1.0) > 0.5)).astype(np.float32)
    fields = {m: Field2D((N, N), p, method=m) for m in ("active", "fft")}
    for _ in range(5):
        for f in fields.values():
            f.step((A[:, None], B[None, :]))
    outs = {m: f.output() for m, f in fields.items()}
    f = outs["active"]
    i, j = np.argwhere(f > 0.5).mean(axis=0)               # centre of the active block
    assert abs(i - 30) <= 1 and abs(j - 300) <= 1 and f.max() > 0.9
    assert f[30, 100] < 1e-6 and f[100, 300] < 1e-6        # ridges alone stay inactive
    np.testing.assert_allclose(outs["active"], outs["fft"], atol=1e-4)
    lat_a = fields["active"].lateral(method="active")
    lat_f = fields["active"].lateral(method="fft")
    np.testing.assert_allclose(lat_a, lat_f, atol=1e-4)
    assert np.argmax(diagonal_sum(f)) == 270                # 300 - 30
    rows, cols, block = fields["active"].active_block()
    assert set(rows) <= set(range(20, 41)) and set(cols) <= set(range(290, 311))
    np.testing.assert_allclose(block, f[np.ix_(rows, cols)])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_field2d_ridges_across_the_boundary_with_two_terms_match_fft(dtype):
    """The compiled ridge step (dt = tau, two ridges) on a non-square field whose active
    block wraps around both periodic boundaries, with excitation and inhibition, in both
    dtypes: the same activation as the exact FFT step."""
    p = FieldParams(tau=1.0, h=-6.0, beta=4.0, c_exc=0.4, sigma_exc=3 * DEG, c_inh=0.1, sigma_inh=8 * DEG,
                    c_glob=0.001)
    n0, n1 = 180, 120
    a = np.zeros(n0, dtype)
    a[np.r_[176:180, 0:3]] = 4.0
    a[60:63] = 4.0
    b = np.zeros(n1, dtype)
    b[np.r_[118:120, 0:4]] = 4.0
    fields = {m: Field2D((n0, n1), p, dtype=dtype, method=m) for m in ("active", "fft")}
    blocks = []
    for _ in range(6):
        for f in fields.values():
            f.step((a[:, None], b[None, :]))
        blocks.append(fields["active"].active_block()[2].shape)
    out = fields["active"].output()
    assert out[0, 0] > 0.9 and out[178, 119] > 0.9 and out[61, 1] > 0.9 and out[100, 60] < 1e-6
    assert all(r > 0 for r, _ in blocks[1:])
    np.testing.assert_allclose(fields["active"].u, fields["fft"].u, atol=1e-3)
    rows, cols, block = fields["active"].active_block()
    assert {0, 179} <= set(rows) and {0, 119} <= set(cols)
    np.testing.assert_allclose(block, out[np.ix_(rows, cols)])


def test_lateral_inputs_of_several_fields_equal_each_fields_own():
    fields = [Field1D(N, DRIVEN), Field1D(N, SUSTAINED), Field1D(N, FieldParams(c_exc=1.0, c_glob=0.01))]
    for i, f in enumerate(fields):
        f.step(bump(40.0 * i + 10.0, amp=9.0))
    lat = lateral_inputs(fields)
    assert lat.shape == (3, N)
    for row, f in zip(lat, fields):
        assert np.array_equal(row, f.lateral())          # the same values, to the bit
    twin = [Field1D(N, DRIVEN), Field1D(N, DRIVEN)]
    for f in twin:
        f.u = fields[0].u.copy()
    out_given = twin[0].step(bump(15.0), lateral=lateral_inputs(twin[:1])[0])
    out_own = twin[1].step(bump(15.0))
    assert np.array_equal(out_given, out_own) and out_own.max() > 0.1   # a peak, not rest (2e-9)
    with pytest.raises(ValidationError, match="lateral"):
        twin[0].step(0.0, lateral=np.zeros(N - 1))
    with pytest.raises(ValidationError, match="same number of sites"):
        lateral_inputs([Field1D(N), Field1D(N // 2)])
    with pytest.raises(ValidationError, match="non-empty list of Field1D"):
        lateral_inputs([])


def test_field2d_slow_field_active_method_matches_fft_with_generic_stimulus():
    p = FieldParams(tau=3.0, h=-6.0, beta=4.0, c_exc=0.4, sigma_exc=3 * DEG, c_inh=0.05, sigma_inh=10 * DEG,
                    c_glob=0.001)
    S = np.zeros((N, N), np.float32)
    S[100:108, 50:60] = 9.0
    S[np.ix_(np.r_[356:360, 0:4], np.r_[355:360, 0:3])] = 9.0       # a block across both boundaries
    a, b = Field2D((N, N), p, method="active"), Field2D((N, N), p, method="fft")
    for _ in range(15):
        a.step(S)
        b.step(S)
    assert a.output().max() > 0.9
    np.testing.assert_allclose(a.u, b.u, atol=1e-3)


def test_field_validation():
    with pytest.raises(ValidationError, match="tau"):
        FieldParams(tau=0.0)
    with pytest.raises(ValidationError, match="sites"):
        Field1D(2)
    with pytest.raises(ValidationError, match="shape"):
        Field2D((10, 10)).u = np.zeros((3, 3))
