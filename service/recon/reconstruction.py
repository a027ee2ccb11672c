"""The reconstruction result: p0 with its coordinate vectors and the parameters used."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Reconstruction"]


@dataclass
class Reconstruction:
    """A reconstructed initial-pressure image p0, with its coordinates and parameters.

    Parameters
    ----------
    p0, z, x, y, params, p0_unit
        As the attributes below.

    Attributes
    ----------
    p0 : ndarray, shape ``(n_z, n_x)`` (2-D) or ``(n_z, n_y, n_x)`` (3-D)
        Initial pressure in the units of the data (Pa when calibrated); row 0 at the sensor
        plane z = 0.
    z : ndarray, shape ``(n_z,)``
        Depths in m (z_j = j dz).
    x : ndarray, shape ``(n_x,)``
        Lateral coordinates in m.
    y : ndarray, shape ``(n_y,)``, or None
        Lateral coordinates in m; None in 2-D.
    params : dict
        Every parameter the reconstruction used (JSON-serialisable).
    p0_unit : str
        ``"Pa"`` when the input was calibrated pressure (a scan whose instrument records its
        volts-to-pascal calibration), else ``"a.u."`` (``fpscan.service.storage.loader.p0_unit``;
        set by ``fpscan.service.pipeline.reconstruct``).
    ndim : int
        2 for a line-sensor (x, z) image, 3 for a plane-sensor volume.

    Examples
    --------
    >>> import numpy as np
    >>> from fpscan.service.recon import Reconstruction
    >>> r = Reconstruction(p0=np.zeros((4, 3)), z=np.arange(4) * 1e-4, x=np.array([-1e-4, 0.0, 1e-4]))
    >>> r.ndim, r.y, r.p0_unit
    (2, None, 'a.u.')
    """

    p0: np.ndarray
    z: np.ndarray
    x: np.ndarray
    y: np.ndarray | None = None
    params: dict = field(default_factory=dict)
    p0_unit: str = "a.u."

    def __repr__(self) -> str:
        """One line: the method, p0's shape, axes, unit and peak, and each axis's extent
        (never the arrays).

        Examples
        --------
        >>> import numpy as np
        >>> from fpscan.service.recon import Reconstruction
        >>> Reconstruction(p0=np.ones((4, 3)), z=np.arange(4) * 1e-4, x=np.array([-1e-4, 0.0, 1e-4]),
        ...                params={"method": "ner"})
        Reconstruction(ner: p0 (4, 3) float64 (n_z, n_x) a.u., max 1, z 0 to 0.3 mm, x -0.1 to 0.1 mm)
        """
        axes = "(n_z, n_x)" if self.p0.ndim == 2 else "(n_z, n_y, n_x)"
        method = self.params.get("method")
        peak = f", max {float(np.max(self.p0)):.4g}" if self.p0.size else ""
        extents = [(name, v) for name, v in (("z", self.z), ("y", self.y), ("x", self.x)) if v is not None and len(v)]
        span = "".join(f", {name} {float(v[0]) * 1e3:.4g} to {float(v[-1]) * 1e3:.4g} mm" for name, v in extents)
        return (f"Reconstruction({method + ': ' if method else ''}p0 {tuple(self.p0.shape)} {self.p0.dtype} {axes} "
                f"{self.p0_unit}{peak}{span})")

    def _repr_html_(self) -> str:
        """A table for notebooks: the method, p0's shape, unit and peak, each axis's extent (mm)
        and every parameter used (never the arrays)."""
        from fpscan.wire.brief import brief, html_table

        extents = [(f"{name} (mm)", f"{float(v[0]) * 1e3:.4g} to {float(v[-1]) * 1e3:.4g}")
                   for name, v in (("z", self.z), ("y", self.y), ("x", self.x)) if v is not None and len(v)]
        return html_table("Reconstruction", [
            ("method", self.params.get("method")), ("p0", f"{tuple(self.p0.shape)} {self.p0.dtype}"),
            ("unit", self.p0_unit), ("max", f"{float(np.max(self.p0)):.4g}" if self.p0.size else None), *extents,
            *((k, brief(v)) for k, v in self.params.items() if k != "method")])

    @property
    def ndim(self) -> int:
        """2 for a line-sensor (x, z) image, 3 for a plane-sensor volume."""
        return self.p0.ndim
