"""Maximum-intensity projections (MIPs), depth slices and their PNG rendering.

Images follow DESIGN §3: ``(n_z, n_y, n_x)`` in 3-D, ``(n_z, n_x)`` in 2-D, row 0 at the
sensor plane. MIP planes: ``xy`` = max over z → ``(n_y, n_x)``; ``xz`` = max over y →
``(n_z, n_x)``; ``yz`` = max over x → ``(n_z, n_y)``. In 2-D only ``xz`` exists (the image).
PNGs are 8-bit greyscale scaled from 0 to the maximum of the projection (Pillow).
"""
from __future__ import annotations

import io

import numpy as np

from service.storage.render import PLANES, mip, to_uint8

__all__ = ["PLANES", "mip", "png_bytes", "mip_pngs"]


def png_bytes(image: np.ndarray) -> bytes:
    """8-bit greyscale PNG of a 2-D array: 0 → black, max(image, 0) → white (negative
    values clip to black; an all-zero or non-finite image renders black)."""
    from PIL import Image as PILImage

    a = np.asarray(image, dtype=np.float64)
    if a.ndim != 2:
        raise ValueError(f"a PNG needs a 2-D array, got shape {a.shape}")
    a = np.where(np.isfinite(a), a, 0.0)
    buf = io.BytesIO()
    PILImage.fromarray(to_uint8(a, vmin=0.0), mode="L").save(buf, format="PNG")
    return buf.getvalue()


def mip_pngs(p0: np.ndarray) -> dict[str, bytes]:
    """PNG bytes of every MIP the image has: ``{plane: png}``."""
    planes = PLANES if np.ndim(p0) == 3 else ("xz",)
    return {plane: png_bytes(mip(p0, plane)) for plane in planes}
