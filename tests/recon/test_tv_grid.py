"""tv's grid: the band-limited resampling and its transpose, the band-limited
operator (dot test; its forward against `forward_points` at the new rate, and against the data
resampled by `fpscan.physics.resample`), the band the lateral pitch resolves, the record kept
for what the image draws on, tv honouring a given dz / n_z and recording its grid, and the grid
module loading no solver (the package exports its names on first use)."""
from __future__ import annotations

import numpy as np
import pytest

from fpscan.physics.forward import forward_points
from fpscan.physics.resample import resample, resample_adjoint, resampled_length
from fpscan.service.metrics import correlation_coefficient
from fpscan.service.recon.operator import PlanarOperator
from fpscan.service.recon.tv import reconstruct_tv
from fpscan.service.recon.tv.grid import RecordFacts, data_extent, noise_sigma, record_facts, tv_grid

C, DX = 1500.0, 60e-6
rng = np.random.default_rng(47)


def test_resampling_is_exact_on_its_band_and_its_transpose_is_the_adjoint():
    t = np.linspace(0.0, 1.0, 97)  # a record of 97 samples on [0, 1]
    terms = [(0.0, 0.3), (4.5, 1.0), (11.0, -0.7)]  # cosines of 4.5 and 11 periods: DCT-I terms 9 and 22
    series = lambda tt: sum(a * np.cos(2 * np.pi * f * tt) for f, a in terms)
    for m in (24, 40, 97, 150):  # every term kept (k <= m - 2), down- and up-sampled
        np.testing.assert_allclose(resample(series(t), m), series(np.linspace(0, 1, m)), atol=1e-12)
    low = resample(series(t), 20)  # terms up to k = 18: the 11-period cosine is cut, exactly
    np.testing.assert_allclose(low, series(np.linspace(0, 1, 20)) + 0.7 * np.cos(2 * np.pi * 11 * np.linspace(0, 1, 20)),
                               atol=1e-12)
    u, v = rng.standard_normal((3, 97)), rng.standard_normal((3, 31))
    assert np.isclose(np.vdot(resample(u, 31, axis=1), v), np.vdot(u, resample_adjoint(v, 97, axis=1)), rtol=1e-12)
    assert resampled_length(1024, 8e-9, 20e6) == 330 and resampled_length(1024, 8e-9, 62.5e6) == 1024
    with pytest.raises(ValueError, match="at least 2"):
        resample(np.ones(1), 5)


def _blob(shape, dz, width):
    """A Gaussian blob of σ = ``width`` (m) at mid-depth: at 100 µm its spectrum is
    negligible above the band below (|k| σ = 8.7 at its edge) and so is its cut at the
    image's borders (4σ away and more)."""
    z = np.arange(shape[0]) * dz
    axes = [(np.arange(n) - (n - 1) / 2) * DX for n in shape[1:]]
    grids = np.meshgrid(z, *axes, indexing="ij")
    r2 = (grids[0] - z[shape[0] // 2]) ** 2 + sum(a**2 for a in grids[1:])
    return np.exp(-r2 / (2 * width**2))


@pytest.mark.parametrize("shape", [(30, 24), (28, 20, 20)], ids=["2d", "3d"])
def test_the_band_limited_operator_is_the_model_at_the_new_rate(shape):
    """At dt' = 3 dt the band-limited operator (f_c = the new Nyquist frequency) passes the dot
    test, equals `forward_points` sampled at dt' for a blob with no energy above the band, and
    equals that model at dt resampled to dt' (the data's path in tv; the record reaches past
    the blob's last echo: where a record ends mid-signal, the resampling's even extension
    has a kink there and its error gathers in the last few samples)."""
    dt = 8e-9
    n_t = 3 * 40 + 1
    m = 41
    dt_m = (n_t - 1) * dt / (m - 1)
    band = 1 / (2 * dt_m)
    dz = C * dt_m
    d = len(shape) - 1
    pos = (rng.uniform(-0.45, 0.45, (9, d)) * np.array(shape[1:][::-1]) * DX)
    op = PlanarOperator(shape, DX, dz, dt_m, m, C, positions=pos, band=band, eps=1e-12)
    x, y = rng.standard_normal(op.ishape), rng.standard_normal(op.oshape)
    lhs, rhs = np.vdot(op.forward(x), y), np.vdot(x, op.adjoint(y))
    assert abs(lhs - rhs) <= 1e-10 * abs(lhs)
    p0 = _blob(shape, dz, 100e-6)
    new_rate = forward_points(p0, DX, dz, pos, dt_m, m, C, eps=1e-12)
    g = op.forward(p0)
    assert np.abs(g - new_rate).max() <= 1e-4 * np.abs(new_rate).max()
    at_dt = forward_points(p0, DX, dz, pos, dt, n_t, C, eps=1e-12)
    assert np.abs(resample(at_dt, m, axis=1) - g).max() <= 2e-3 * np.abs(g).max()
    # without the band limit the samples at dt' alias what lies above it: a voxel-sized source
    spike = np.zeros(shape)
    spike[(shape[0] // 2,) + tuple(n // 2 for n in shape[1:])] = 1.0
    plain = PlanarOperator(shape, DX, dz, dt_m, m, C, positions=pos, eps=1e-12).forward(spike)
    limited = op.forward(spike)
    assert np.abs(plain - limited).max() > 0.05 * np.abs(limited).max()


def test_the_band_is_what_the_lateral_pitch_resolves_and_the_same_for_any_record():
    """Without a declared band, tv's band is c / (2 pitch) (an isotropic grid: dz =
    the pitch), whatever the data's noise or the record's length (a cut and the whole record
    give the same band); a declared sensor band replaces it, lower or higher; at or above the
    record's Nyquist frequency there is no band; a given dz or n_z is honoured."""
    t = np.arange(600) * 10e-9  # Nyquist 50 MHz; 60 µm resolves 12.5 MHz
    rng2 = np.random.default_rng(1)
    pulse = np.exp(-0.5 * ((t[None, :] - rng2.uniform(1e-6, 3e-6, (40, 1))) / 50e-9) ** 2)
    grids = [tv_grid(600, 10e-9, C, data=pulse + sigma * rng2.standard_normal(pulse.shape), time_axis=1,
                     pitch=DX, reach=reach, whole_record=whole)
             for sigma in (1e-1, 1e-2, 1e-4) for reach in (0.0, 1e-3, None) for whole in (False, True)]
    assert {(g.band, g.reason, g.dz) for g in grids} == {(C / (2 * DX), "lateral", DX)}
    for g in grids:  # the kept record, resampled to the fewest samples whose band reaches 12.5 MHz
        assert g.n_t == resampled_length(g.record_n_t, 10e-9, g.band) < g.record_n_t
        assert np.isclose(g.dt, (g.record_n_t - 1) * 10e-9 / (g.n_t - 1))
    assert tv_grid(600, 10e-9, C, pitch=DX, bandwidth=5e6).band == 5e6  # a declared lower band
    high = tv_grid(600, 10e-9, C, pitch=DX, bandwidth=20e6)  # a declared higher band: the sensor's word
    assert (high.band, high.reason, high.dz) == (20e6, "declared", C / 40e6)
    coarse = tv_grid(600, 10e-9, C, pitch=200e-9)  # 3.75 GHz: above the record's Nyquist, no band
    assert (coarse.band, coarse.reason, coarse.n_t, coarse.dz) == (None, "nyquist", 600, C * 10e-9)
    assert tv_grid(600, 10e-9, C).reason == "nyquist"  # no pitch known: the record's own band
    kept = tv_grid(600, 10e-9, C, data=pulse, time_axis=1, pitch=DX, dz=5e-6, n_z=77)  # given: honoured
    assert (kept.dz, kept.n_z, kept.band) == (5e-6, 77, C / (2 * DX))
    one = tv_grid(600, 10e-9, C, pitch=DX, n_z=77)  # one given: the other by the depth grid's rule
    assert (one.dz, one.n_z) == (C / (2 * one.band), 77) and np.isclose(one.dz, DX)
    # dz alone: rows reaching c·t_last = c · 599 · 10 ns (8.985 mm)
    assert tv_grid(600, 10e-9, C, pitch=DX, dz=5e-6).n_z == int(np.floor(C * 599 * 10e-9 / 5e-6 + 1e-9)) + 1
    for bad in ({"pitch": 0.0}, {"pitch": np.nan}, {"reach": -1.0}, {"bandwidth": -1.0}):
        with pytest.raises(ValueError):
            tv_grid(600, 10e-9, C, **bad)


def test_the_record_is_kept_until_the_farthest_sensor_hears_the_images_last_row():
    """In 3-D the record is cut only where the model of the image predicts silence
    at every sensor: the forward model (`forward_points`) of a source at the image's deepest row,
    at the lateral corner farthest from a sensor, has passed that sensor before the kept record
    ends (and not long before). A line's sources ring on (2-D waves have a tail ∝ 1/t²):
    tv keeps a line's whole record (`fpscan.service.recon.tv.problem.lateral_extent` gives no reach there)."""
    n_t, dt = 900, 10e-9
    x = (np.arange(24) - 11.5) * DX  # the image's lateral axes (x and y)
    pos = np.array([[x[0], x[0]], [x[3], x[2]]])  # two sensors at one corner of the image
    reach = float(np.hypot(x[-1] - x[0], x[-1] - x[0]))  # the farthest corner from the first sensor
    t = np.arange(n_t)
    data = np.where((t > 150) & (t < 200), 1.0, 0.0) + 1e-3 * rng.standard_normal((2, n_t))  # echoes end by 200
    g = tv_grid(n_t, dt, C, data=data, time_axis=1, pitch=DX, reach=reach)
    assert g.extent_reason == "image" and g.record_n_t < n_t
    depth = (g.n_z - 1) * g.dz
    assert C * 199 * dt <= depth <= C * 230 * dt  # the default image ends at the signal's end (and its margin)
    # a blob of one voxel's σ at the deepest row's farthest corner (2 voxels in: whole): its N-wave at the
    # first sensor has passed (below 1 % of its peak; the discrete model's own ringing stays below 0.5 %)
    zz, yy, xx = np.meshgrid(np.arange(g.n_z) * g.dz, x, x, indexing="ij")
    p0 = np.exp(-((zz - zz[-3, 0, 0]) ** 2 + (yy - x[-3]) ** 2 + (xx - x[-3]) ** 2) / (2 * DX**2))
    heard = forward_points(p0, DX, g.dz, pos[:1], dt, n_t, C)[0]
    last = int(np.flatnonzero(np.abs(heard) > 1e-2 * np.abs(heard).max())[-1])
    assert last < g.record_n_t <= last + 2 * max(4, int(np.ceil(0.02 * n_t))), (last, g.record_n_t)
    assert tv_grid(n_t, dt, C, data=data, time_axis=1, pitch=DX, reach=reach, whole_record=True).record_n_t == n_t
    assert tv_grid(n_t, dt, C, data=data, time_axis=1, pitch=DX).record_n_t == n_t  # no reach known: all kept


def test_tv_on_band_limited_data_works_on_a_coarser_grid_and_says_so():
    """Data of a smooth 2-D source sampled at 100 MHz by sensors 120 µm apart on an image of 60 µm:
    tv works at the 12.5 MHz the lateral pitch resolves (fewer samples), records the grid and why,
    keeps a given dz and n_z, and its image matches the source."""
    shape, dt, n_t = (48, 40), 10e-9, 160
    dz = C * dt
    p0 = _blob(shape, dz, 160e-6) + 0.6 * _blob(shape, dz, 90e-6)
    sensors = np.arange(0, shape[1], 2)
    pos = ((sensors - (shape[1] - 1) / 2) * DX)[:, None]
    clean = forward_points(p0, DX, dz, pos, dt, n_t, C)
    noisy = clean + rng.standard_normal(clean.shape) * float(np.sqrt(np.mean(clean**2))) / 10 ** 1.5
    x = (np.arange(shape[1]) - (shape[1] - 1) / 2) * DX
    rec = reconstruct_tv(noisy, dt, C, positions=pos, grid=(x,), n_z=shape[0], dz=dz, max_iter=60)
    p = rec.params
    assert p["band_reason"] == "lateral" and p["operator_n_t"] < n_t and np.isclose(p["band"], C / (2 * DX))
    assert np.isclose(p["operator_dt"], (p["record_n_t"] - 1) * dt / (p["operator_n_t"] - 1))
    assert rec.p0.shape == shape and np.isclose(rec.z[1], dz)  # the given depth grid, kept
    assert correlation_coefficient(rec.p0, p0) > 0.95
    default = reconstruct_tv(noisy, dt, C, positions=pos, grid=(x,), max_iter=3)
    assert np.isclose(default.z[1], DX)  # the default grid is isotropic


def test_the_records_extent_is_read_off_the_data_above_their_noise():
    """`data_extent`: pulses in white noise are kept past the last sample where they beat σ,
    and at most the margin (2 % of the record: 16 samples) further; noise alone, and a
    signal in the last samples, cut nothing."""
    rng2 = np.random.default_rng(3)
    t = np.arange(800)
    for end, sigma in ((300, 1e-2), (520, 1e-3)):
        # 40 A-lines of Gaussian pulses of 8 samples' width whose last one peaks 30 samples before ``end``
        peaks = np.append(rng2.uniform(100, end - 30, 39), end - 30)[:, None]
        clean = np.exp(-0.5 * ((t - peaks) / 8.0) ** 2)
        g = clean + sigma * rng2.standard_normal((40, 800))
        k = data_extent(g, 1, noise_sigma(g, 1))
        above = int(np.flatnonzero(clean.max(axis=0) > sigma)[-1])  # the pulses' last sample above σ
        assert k is not None and above < k <= above + 17, (above, k)
        assert data_extent(g.T, 0, noise_sigma(g, 1)) == k  # time first: the same
    assert data_extent(rng2.standard_normal((40, 800)), 1, 1.0) is None  # noise alone
    late = np.exp(-0.5 * ((t - 790) / 8.0) ** 2) + 1e-3 * rng2.standard_normal((40, 800))
    assert data_extent(late, 1, 1e-3) is None  # the signal lasts to the end
    assert data_extent(late, 1, 0.0) is None  # no noise estimate: nothing to compare with


def test_tv_images_down_to_the_last_echo_keeps_what_the_image_draws_on_and_a_given_depth():
    """A 2-D source whose echoes beat the noise until sample 64-127 of a 400-sample record: tv's
    default image reaches the depth of the last echo, the record is kept until the farthest sensor
    hears its last row, its image matches the source about as well as the whole record's does
    (``whole_record``), and a depth the caller gives is reached (the record kept to it)."""
    shape, dt, n_t = (60, 40), 40e-9, 400
    dz = C * dt
    p0 = _blob(shape, dz, 120e-6)
    sensors = np.arange(0, shape[1], 2)
    pos = ((sensors - (shape[1] - 1) / 2) * DX)[:, None]
    clean = forward_points(p0, DX, dz, pos, dt, n_t, C)
    sigma = float(np.sqrt(np.mean(clean**2))) / 10 ** 1.5
    noisy = clean + np.random.default_rng(5).standard_normal(clean.shape) * sigma
    # the last sample an echo beats the universal threshold at a sensor (5.2 σ for these 8000 samples; 6 σ: the
    # noise cannot hide it: 64)
    heard = np.flatnonzero(np.abs(clean).max(axis=0) > 6 * sigma)[-1]
    x = (np.arange(shape[1]) - (shape[1] - 1) / 2) * DX

    def truth(rec):  # the blob (centre 30 dz deep) on tv's grid
        zz, xx = np.meshgrid(rec.z, x, indexing="ij")
        return np.exp(-((zz - 30 * dz) ** 2 + xx**2) / (2 * 120e-6**2))

    cut = reconstruct_tv(noisy, dt, C, positions=pos, grid=(x,), max_iter=60)
    p = cut.params
    assert cut.z[-1] >= C * heard * dt and np.isclose(cut.z[1], DX)
    far = float(np.hypot(cut.z[-1], x[-1] - pos[0, 0])) / C  # the farthest sensor hears the last row then
    assert p["record_n_t"] == n_t or (p["extent_reason"] == "image" and p["record_n_t"] * dt > far)
    whole = reconstruct_tv(noisy, dt, C, positions=pos, grid=(x,), whole_record=True, max_iter=60)
    assert whole.params["extent_reason"] == "record" and whole.params["record_n_t"] == n_t
    assert whole.params["whole_record"] is True and p["whole_record"] is False
    assert correlation_coefficient(cut.p0, truth(cut)) > 0.95
    assert correlation_coefficient(cut.p0, truth(cut)) >= correlation_coefficient(whole.p0, truth(whole)) - 0.01
    deep = reconstruct_tv(noisy, dt, C, positions=pos, grid=(x,), n_z=300, max_iter=2)
    assert deep.params["record_n_t"] >= 300 and deep.p0.shape[0] == 300


def test_record_facts_give_the_grid_the_data_give_and_read_sigma_from_a_sample_of_a_large_record():
    """`record_facts` (what a server stores at a dataset's import, for its admission) lead
    `tv_grid` to the grid the data themselves lead it to, for A-lines and for time-first grid
    data, at the default depth and at a given one; a record of more than 2 × 4 million samples
    has σ read from every k-th A-line, within 0.5 % of the whole record's, and the same extent.
    Facts of another record length are refused; a stored dict comes back as it went, and one
    stored before the band left the facts (with its ``band``) still reads."""
    n_t, dt = 600, 8e-9
    t = np.arange(n_t)
    echo = np.where((t > 150) & (t < 230), np.sin(t / 3.0), 0.0)  # the echoes end at sample 230
    local = np.random.default_rng(11)
    alines = echo + 0.02 * local.standard_normal((300, n_t))
    grid = np.moveaxis(alines.reshape(15, 20, n_t), -1, 0).copy()  # (n_t, n_y, n_x), the same record
    lateral = dict(pitch=DX, reach=1e-3)
    for data, axis in ((alines, 1), (grid, 0)):
        facts = record_facts(data, dt, axis)
        assert facts.n_t == n_t and 230 < facts.signal_n_t < 300 and facts.sigma == noise_sigma(data, axis)
        for given in ({}, {"n_z": 400}, {"dz": 2 * C * dt}):
            assert tv_grid(n_t, dt, C, facts=facts, **lateral, **given) == tv_grid(
                n_t, dt, C, data=data, time_axis=axis, **lateral, **given)
        assert RecordFacts.from_dict(facts.as_dict()) == facts
        assert RecordFacts.from_dict({**facts.as_dict(), "band": 7.5e6}) == facts
    with pytest.raises(ValueError, match="600 samples, not 601"):
        tv_grid(n_t + 1, dt, C, facts=record_facts(alines, dt, 1))
    big = (echo + 0.02 * local.standard_normal((15000, n_t))).astype(np.float32)  # 9 million samples
    facts = record_facts(big, dt, 1)
    whole = noise_sigma(big, 1)
    assert abs(facts.sigma / whole - 1) < 0.005
    assert facts.signal_n_t == data_extent(big, 1, whole)


def test_the_grid_loads_no_solver_and_the_package_exports_on_first_use():
    """`fpscan.service.recon.tv.grid` is pure numpy (the server sizes a tv job from it): importing
    it loads neither numba nor the solver's modules; the package's public names come from the
    modules that own them, on first use."""
    import json
    import subprocess
    import sys

    code = ("import json, sys\n"
            "import fpscan.service.recon.tv.grid\n"
            "before = sorted(m for m in sys.modules if m.split('.')[0] == 'numba' or m.startswith('fpscan.service.recon.tv.'))\n"
            "import fpscan.service.recon.tv as tv\n"
            "owners = {name: getattr(tv, name).__module__ for name in tv.__all__ if callable(getattr(tv, name))}\n"
            "print(json.dumps({'before': before, 'owners': owners}))\n")
    got = json.loads(subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout)
    assert got["before"] == ["fpscan.service.recon.tv.grid"], got["before"]
    assert got["owners"] == {"TvGrid": "fpscan.service.recon.tv.grid", "noise_sigma": "fpscan.service.recon.tv.grid",
                             "reconstruct_tv": "fpscan.service.recon.tv.reconstruct",
                             "tv_problem": "fpscan.service.recon.tv.reconstruct",
                             "TvProblem": "fpscan.service.recon.tv.formulation",
                             "tv_grid": "fpscan.service.recon.tv.grid"}, got["owners"]
