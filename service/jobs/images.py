"""Maximum-intensity projections (MIPs), depth slices and their PNG rendering.

Images follow DESIGN §3: ``(n_z, n_y, n_x)`` in 3-D, ``(n_z, n_x)`` in 2-D, row 0 at the
sensor plane. MIP planes: ``xy`` = max over z → ``(n_y, n_x)``; ``xz`` = max over y →
``(n_z, n_x)``; ``yz`` = max over x → ``(n_z, n_y)``. In 2-D only ``xz`` exists (the image).
PNGs are 8-bit greyscale scaled from 0 to the maximum of the projection (Pillow).
"""
from __future__ import annotations

import io

import numpy as np

PLANES = ("xy", "xz", "yz")


def mip(p0: np.ndarray, plane: str) -> np.ndarray:
    """The maximum-intensity projection of ``p0`` on ``plane``; raises ``ValueError`` for
    an unknown plane or one a 2-D image does not have."""
    p0 = np.asarray(p0)
    if plane not in PLANES:
        raise ValueError(f"plane must be one of {', '.join(PLANES)}, not {plane!r}")
    if p0.ndim == 2:
        if plane != "xz":
            raise ValueError("a 2-D image has only the xz plane")
        return p0
    if p0.ndim != 3:
        raise ValueError(f"p0 must be 2-D or 3-D, got {p0.ndim}-D")
    axis = {"xy": 0, "xz": 1, "yz": 2}[plane]
    return p0.max(axis=axis)


def png_bytes(image: np.ndarray) -> bytes:
    """8-bit greyscale PNG of a 2-D array: 0 → black, max(image, 0) → white (negative
    values clip to black; an all-zero or non-finite image renders black)."""
    from PIL import Image as PILImage

    a = np.nan_to_num(np.asarray(image, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    if a.ndim != 2:
        raise ValueError(f"a PNG needs a 2-D array, got shape {a.shape}")
    top = a.max() if a.size else 0.0
    scaled = np.clip(a / top, 0.0, 1.0) if top > 0 else np.zeros_like(a)
    buf = io.BytesIO()
    PILImage.fromarray((scaled * 255.0 + 0.5).astype(np.uint8), mode="L").save(buf, format="PNG")
    return buf.getvalue()


def mip_pngs(p0: np.ndarray) -> dict[str, bytes]:
    """PNG bytes of every MIP the image has: ``{plane: png}``."""
    planes = PLANES if np.ndim(p0) == 3 else ("xz",)
    return {plane: png_bytes(mip(p0, plane)) for plane in planes}
