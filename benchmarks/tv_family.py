"""A family of phantoms that no tv rule was tuned on: seeded mixes of balls and vessel segments at the
paper's sampling, for tv's quality gate (`bench_tv_matrix.py --cases family family-full`).

Every member is one scan of the paper's kind (`bench_tv_paper`: c = 1500 m/s, a square lattice of
60 µm, samples of 8 ns) with its own seed, its own sensor mask and its own noise:

- **size**: `HALF` members at half the paper's lattice (113², 6.78 mm a side) and `FULL` at its full
  size (226², 13.56 mm), named ``family-00`` ... and ``family-full-0`` ...;
- **held out**: `HOLDOUT` more half-size members, ``family-holdout-0`` ..., made by the same rules
  (indices `HALF` ... at half size, so seeds 1024 ...; member j has the j-th of `COMBOS`, every mask ×
  noise once). No default was chosen on them: a choice made by measuring the family (a threshold, a
  cap) is judged on them (``bench_tv_matrix.py --cases family-holdout``);
- **objects** (`family_objects`, numpy's ``default_rng(seed)``; the seed is 1000 + index at half size
  and 2000 + index at full size): 1-4 uniform balls of radius 0.1-0.4 mm and 1-3 vessel segments of
  radius 0.05-0.2 mm and length 1-3 mm, half of them straight and half bent (a quadratic Bézier curve
  whose middle control point stands off the chord by up to a fifth of its length, in a random
  direction across it), each of amplitude 0.5-1, every ball centre 1.5-6 mm deep and within the
  central half of the lattice laterally (|x|, |y| <= a quarter of its side), so that each object is
  seen by a wide aperture and the depths span the issue's 1.5-6 mm;
- **vessels as chains of balls**: a segment of radius R is the sum of balls of radius R whose centres
  lie on its centre line at most R / 2 apart along its arc (`VESSEL_STEP`), each of amplitude A·3s / (4R)
  (s the chain's spacing), so that p0's mean over the tube is A (a ball's volume 4πR³/3 over s of
  length against the tube's πR² s). Both the data and p0 are then the superposition of exact
  uniform balls: the A-lines are the closed-form N-waves of `fpscan.physics.ball_alines`, averaged
  over each sample (Diebold & Westervelt 1988), not fpscan's own forward model (no inverse crime),
  and p0 is the balls' amplitude-weighted indicator, overlaps summed (`balls_p0`);
- **the record** (``n_t``): long enough for the last echo, the far side of the object farthest from a
  lattice corner: ``n_t`` = the smallest multiple of 16 >= 1.02 r_far / (c dt) + 8, r_far the largest
  corner-to-centre distance plus the radius (about 800 samples at half size and 1300 at full);
- **mask and noise**: half-size member i has the (i mod 8)-th of `COMBOS`, so that every mask (4 % and 11 %
  equi-steradian, `bench_tv_matrix.make_mask`, around a point under the lattice centre at p0's
  centroid depth) meets every noise (20, 30 and 40 dB below the peak and 30 dB below the RMS,
  `bench_tv_matrix.noisy`, seeded by the member's seed) three times in 24 members; the 3 full-size
  members take `FULL_COMBOS`: the strongest noise at the sparser mask, the weakest peak noise at the
  denser one, and 30 dB RMS at 4 %, where the stopping rule missed on the matrix's balls.

`family_case` gives a member as `bench_tv_matrix.load_case` gives its cases (the dense record
``clean`` ``(n_t, n_y, n_x)`` of every lattice point, ``p0`` None: the CC is with `balls_p0` on tv's
own image grid, as for the paper's case).
"""
from __future__ import annotations

import math
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_tv_paper import DT, PITCH, C  # the paper's sampling (one owner)

#: members at half the paper's lattice (113²) and at its full size (226²)
HALF, FULL = 24, 3
#: held-out half-size members (module doc): indices HALF ... HALF + HOLDOUT - 1 at half size
HOLDOUT = 8
#: (mask %, noise) of every combination; half-size member i takes COMBOS[i % 8]
COMBOS = tuple((m, n) for n in ("peak20", "peak30", "peak40", "rms30") for m in (4, 11))
#: the full-size members' (mask %, noise): module doc
FULL_COMBOS = ((4, "peak20"), (11, "peak40"), (4, "rms30"))
DEPTH = (1.5e-3, 6.0e-3)  # ball centres, m
BALL_RADIUS = (0.1e-3, 0.4e-3)
VESSEL_RADIUS = (0.05e-3, 0.2e-3)
VESSEL_LENGTH = (1.0e-3, 3.0e-3)
AMPLITUDE = (0.5, 1.0)
#: a vessel's chain of balls: centres at most this many radii apart along the centre line
VESSEL_STEP = 0.5
MEMBERS = tuple([f"family-{i:02d}" for i in range(HALF)] + [f"family-full-{j}" for j in range(FULL)]
                + [f"family-holdout-{j}" for j in range(HOLDOUT)])


def member(name: str) -> tuple[int, float]:
    """``(index, scale)`` of a member's name (``family-07``: 7, 0.5; ``family-full-1``: 1, 1.0;
    ``family-holdout-2``: `HALF` + 2, 0.5); ValueError for another name."""
    m = re.fullmatch(r"family-(?:(full|holdout)-)?(\d+)", name)
    count = {"full": FULL, "holdout": HOLDOUT}.get(m[1], HALF) if m is not None else 0
    if m is None or int(m[2]) >= count or (m[1] is None and len(m[2]) != 2):
        raise ValueError(f"not a member of the family: {name!r} (members: family-00 ... family-{HALF - 1}, "
                         f"family-full-0 ... {FULL - 1}, family-holdout-0 ... {HOLDOUT - 1})")
    return (int(m[2]), 1.0) if m[1] == "full" else (int(m[2]) + (HALF if m[1] == "holdout" else 0), 0.5)


def member_scan(index: int, scale: float) -> tuple[int, str]:
    """The member's (mask %, noise): the (index mod 8)-th of `COMBOS` at half size, `FULL_COMBOS`
    [index] at full size (module doc)."""
    return COMBOS[index % len(COMBOS)] if scale == 0.5 else FULL_COMBOS[index]


def member_seed(index: int, scale: float) -> int:
    """The member's seed: 1000 + index at half size, 2000 + index at full size."""
    return int(round(2000 * scale)) + index


def _lattice(scale: float) -> int:
    return int(round(226 * scale))


def _vessel_chain(rng: np.random.Generator, half_side: float) -> tuple[list, dict]:
    """A vessel segment inside the box (module doc) as its chain of balls, and its description."""
    from fpscan.physics import Ball

    radius = rng.uniform(*VESSEL_RADIUS)
    amplitude = rng.uniform(*AMPLITUDE)
    bent = bool(rng.integers(2))
    for _ in range(1000):
        length = rng.uniform(*VESSEL_LENGTH)
        start = np.array([rng.uniform(-half_side, half_side), rng.uniform(-half_side, half_side), rng.uniform(*DEPTH)])
        direction = rng.standard_normal(3)
        direction /= np.linalg.norm(direction)
        across = np.cross(direction, rng.standard_normal(3))
        across /= np.linalg.norm(across)
        end = start + length * direction
        control = (start + end) / 2 + (rng.uniform(-0.2, 0.2) * length if bent else 0.0) * across
        s = np.linspace(0.0, 1.0, 2001)[:, None]
        curve = (1 - s) ** 2 * start + 2 * s * (1 - s) * control + s**2 * end
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])
        n = int(math.ceil(arc[-1] / (VESSEL_STEP * radius))) + 1  # spacing arc / (n - 1) <= R / 2
        centres = np.stack([np.interp(np.linspace(0, arc[-1], n), arc, curve[:, k]) for k in range(3)], axis=1)
        if (np.all(np.abs(centres[:, :2]) <= half_side) and np.all(centres[:, 2] >= DEPTH[0])
                and np.all(centres[:, 2] <= DEPTH[1])):
            step = arc[-1] / (n - 1)
            a = amplitude * 3 * step / (4 * radius)  # the tube's mean p0 = amplitude (module doc)
            balls = [Ball(float(x), float(y), float(z), radius, a) for x, y, z in centres]
            return balls, dict(kind="vessel", radius=radius, amplitude=amplitude, length=float(arc[-1]), bent=bent,
                               step=float(step), balls=n, depth=(float(centres[:, 2].min()), float(centres[:, 2].max())))
    raise RuntimeError("no vessel segment fits the box")  # not reached for the box's sizes here


def family_objects(seed: int, scale: float = 0.5) -> tuple[list, list[dict]]:
    """A member's balls (`fpscan.physics.Ball`; a vessel is its chain, module doc) and one dict per
    object (kind, radius, amplitude, depth range (m), and a vessel's length, bend, spacing and balls)."""
    from fpscan.physics import Ball

    rng = np.random.default_rng(seed)
    half_side = _lattice(scale) * PITCH / 4
    balls: list = []
    objects: list[dict] = []
    for _ in range(int(rng.integers(1, 5))):
        radius, amplitude = rng.uniform(*BALL_RADIUS), rng.uniform(*AMPLITUDE)
        x, y = rng.uniform(-half_side, half_side, 2)
        z = rng.uniform(*DEPTH)
        balls.append(Ball(float(x), float(y), float(z), radius, amplitude))
        objects.append(dict(kind="ball", radius=radius, amplitude=amplitude, depth=(float(z), float(z))))
    for _ in range(int(rng.integers(1, 4))):
        chain, info = _vessel_chain(rng, half_side)
        balls.extend(chain)
        objects.append(info)
    return balls, objects


def record_length(balls: list, scale: float) -> int:
    """Samples that reach the far side of the ball farthest from a lattice corner (module doc)."""
    corner = (_lattice(scale) - 1) / 2 * PITCH
    far = max(math.sqrt((abs(b.x) + corner) ** 2 + (abs(b.y) + corner) ** 2 + b.z**2) + b.radius for b in balls)
    return int(math.ceil((1.02 * far / (C * DT) + 8) / 16)) * 16


def balls_record(positions: np.ndarray, balls: list, dt: float, n_t: int, c: float) -> np.ndarray:
    """The exact A-lines of ``balls`` at ``positions`` ``(n_points, 2)`` (m), as ``(n_t, n_points)`` (Pa):
    `fpscan.physics.ball_alines` of each ball over the few samples where its N-wave reaches each point
    (per-point ``t0``; zero elsewhere), summed. Equals ``ball_alines(positions, balls, dt, n_t, c).T``
    for balls whose nearest surface is above the sensor plane's t = 0 (r > R)."""
    from fpscan.physics import ball_alines

    pos = np.asarray(positions, float)
    cols = np.arange(len(pos))[:, None]
    out = np.zeros((n_t, len(pos)))
    for b in balls:
        r = np.sqrt((pos[:, 0] - b.x) ** 2 + (pos[:, 1] - b.y) ** 2 + b.z**2)
        # nonzero where sample n's interval [n dt - dt/2, n dt + dt/2] meets [(r - R)/c, (r + R)/c]
        first = np.maximum(np.floor((r - b.radius) / (c * dt) - 0.5).astype(int), 0)
        width = int(math.ceil(2 * b.radius / (c * dt))) + 3
        window = ball_alines(pos, b, dt, width, c, t0=first * dt)
        rows = first[:, None] + np.arange(width)
        keep = rows < n_t
        out[rows[keep], np.broadcast_to(cols, rows.shape)[keep]] += window[keep]
    return out


def balls_p0(balls: list, z: np.ndarray, x: np.ndarray, y: np.ndarray, supersample: int = 2) -> np.ndarray:
    """`fpscan.physics.ball_p0` of ``balls`` on the grid ``z, x, y`` (m; uniform axes), ``(n_z, n_y, n_x)``
    (Pa): each ball sampled on the part of the grid around it (its box and one voxel more), summed;
    equal to ``ball_p0(balls, z, x, y, supersample)``, in time for the hundreds of balls of a vessel."""
    from fpscan.physics import ball_p0

    z, x, y = (np.asarray(v, float) for v in (z, x, y))
    out = np.zeros((len(z), len(y), len(x)))

    def window(axis: np.ndarray, centre: float, radius: float) -> slice:
        step = float(axis[1] - axis[0])
        lo = int(np.searchsorted(axis, centre - radius - step))
        hi = int(np.searchsorted(axis, centre + radius + step, side="right"))
        return slice(max(lo - 1, 0), min(hi + 1, len(axis)))

    for b in balls:
        sz, sy, sx = window(z, b.z, b.radius), window(y, b.y, b.radius), window(x, b.x, b.radius)
        if z[sz].size < 2 or y[sy].size < 2 or x[sx].size < 2:
            continue  # the ball is off the grid (a window on the grid holds 3 points or more)
        out[sz, sy, sx] += ball_p0(b, z[sz], x[sx], y[sy], supersample=supersample)
    return out


def family_case(index: int, scale: float = 0.5) -> dict:
    """A member as a case of `bench_tv_matrix` (module doc): ``name``, ``clean`` ``(n_t, n, n)`` (Pa, every
    lattice point, axes (t, y, x) on centred axes), ``p0`` None, ``balls``, ``objects``, ``dt``, ``dx``,
    ``dz`` None, ``c``, ``poi_depth`` (p0's centroid depth, m), ``mask`` (%), ``noise``, ``seed``,
    ``scale``. ValueError for an index outside the family or a scale other than 0.5 and 1."""
    from fpscan.physics.axes import centred_axis

    if scale not in (0.5, 1.0):
        raise ValueError(f"the family's members are at scale 0.5 or 1, got {scale}")
    count = HALF + HOLDOUT if scale == 0.5 else FULL
    if not 0 <= index < count:
        raise ValueError(f"index must be 0 ... {count - 1} at scale {scale}, got {index}")
    seed = member_seed(index, scale)
    balls, objects = family_objects(seed, scale)
    n = _lattice(scale)
    n_t = record_length(balls, scale)
    x = centred_axis(n, PITCH)
    X, Y = np.meshgrid(x, x, indexing="xy")
    pos = np.stack([X.ravel(), Y.ravel()], axis=1)
    clean = balls_record(pos, balls, DT, n_t, C).reshape(n_t, n, n)
    weight = np.array([b.amplitude * b.radius**3 for b in balls])  # each ball's p0 integral / (4π/3)
    depth = float(np.dot(weight, [b.z for b in balls]) / weight.sum())
    mask, noise = member_scan(index, scale)
    name = (f"family-full-{index}" if scale == 1.0 else f"family-{index:02d}" if index < HALF
            else f"family-holdout-{index - HALF}")
    return dict(name=name, clean=clean, p0=None, balls=balls, objects=objects, dt=DT, dx=PITCH, dz=None, c=C,
                poi_depth=depth, mask=mask, noise=noise, seed=seed, scale=scale)


def describe(case: dict) -> str:
    """One line: the member's objects (kind, radius and depth in mm), record, mask and noise."""
    parts = []
    for o in case["objects"]:
        lo, hi = (v * 1e3 for v in o["depth"])
        where = f"{lo:.2f}" if o["kind"] == "ball" else f"{lo:.2f}-{hi:.2f}"
        extra = f", {o['length'] * 1e3:.1f} mm{' bent' if o['bent'] else ''}" if o["kind"] == "vessel" else ""
        parts.append(f"{o['kind']} r {o['radius'] * 1e3:.2f}{extra} at {where}")
    return (f"{case['name']}: {'; '.join(parts)} (mm); {case['clean'].shape[0]} samples; "
            f"{case['mask']} %, {case['noise']}")


if __name__ == "__main__":
    for name in MEMBERS:
        i, s = member(name)
        print(describe(family_case(i, s)) if s == 0.5 or "--full" in sys.argv else name)
