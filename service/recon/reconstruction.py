"""The reconstruction result: p0 with its coordinate vectors and the parameters used."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Reconstruction"]


@dataclass
class Reconstruction:
    """A reconstructed initial-pressure image.

    Attributes
    ----------
    p0 : (n_z, n_x) (2-D) or (n_z, n_y, n_x) (3-D) array, Pa (the units of the data);
        row 0 at the sensor plane z = 0.
    z : (n_z,) depths in m (z_j = j dz).
    x : (n_x,) lateral coordinates in m.
    y : (n_y,) lateral coordinates in m, or None in 2-D.
    params : every parameter the reconstruction used (JSON-serialisable dict).
    p0_unit : the unit of ``p0``: ``"Pa"`` when the input was calibrated pressure (a scan
        whose instrument records its volts-to-pascal calibration), else ``"a.u."``
        (``service.storage.datasets.p0_unit``; set by ``service.pipeline.reconstruct``).
    """

    p0: np.ndarray
    z: np.ndarray
    x: np.ndarray
    y: np.ndarray | None = None
    params: dict = field(default_factory=dict)
    p0_unit: str = "a.u."

    @property
    def ndim(self) -> int:
        """2 for a line-sensor (x, z) image, 3 for a plane-sensor volume."""
        return self.p0.ndim
