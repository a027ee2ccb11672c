"""k-Wave's HDF5 layout as fpscan reads it: which attributes give the lateral spacings.

Sensor data in k-Wave layout are time first, ``(n_t, n_x)`` (k-Wave ``'ty'``) or
``(n_t, n_y, n_x)`` (``'tyz'``), with spacings as attributes of the array or of the file
(the array's first). k-Wave names the depth axis x, so in a k-Wave-named file — a
``kwave_DataOrder`` attribute on the array or ``kwave_commit`` on the file, as the
reference files in ``shared/data`` carry — our lateral x is k-Wave's z (``dz_m``) in 3-D
and k-Wave's y (``dy_m``) in 2-D, and our y is k-Wave's y (``dy_m``); in other files
``dx_m`` and ``dy_m`` are our x and y. The one owner of that rule, for the upload reader
(``fpscan.service.storage.loader``) and the simulator's replay source (``fpscan.driver.sources``).
The sensor coordinates a file may give follow the same naming
(:func:`sensor_coordinate_names`). Pure Python.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any

__all__ = ["attribute", "is_kwave_named", "lateral_spacings", "sensor_coordinate_names"]


def attribute(data_attrs: Mapping[str, Any], file_attrs: Mapping[str, Any], name: str) -> Any:
    """The attribute ``name`` of the array, else of the file, else None.

    Parameters
    ----------
    data_attrs : Mapping[str, Any]
        The array's HDF5 attributes.
    file_attrs : Mapping[str, Any]
        The file's (root group's) HDF5 attributes.
    name : str
        The attribute to look up.

    Returns
    -------
    Any
        Its value as stored, or None where neither has it.
    """
    return data_attrs.get(name, file_attrs.get(name))


def is_kwave_named(data_attrs: Mapping[str, Any], file_attrs: Mapping[str, Any]) -> bool:
    """True for k-Wave's own naming (depth = x): ``kwave_DataOrder`` on the array or
    ``kwave_commit`` on the file.

    Parameters
    ----------
    data_attrs : Mapping[str, Any]
        The array's HDF5 attributes.
    file_attrs : Mapping[str, Any]
        The file's (root group's) HDF5 attributes.

    Returns
    -------
    bool
        Whether the file uses k-Wave's axis names.
    """
    return "kwave_DataOrder" in data_attrs or "kwave_commit" in file_attrs


def lateral_spacings(data_attrs: Mapping[str, Any], file_attrs: Mapping[str, Any],
                     ndim: int) -> tuple[Any, Any]:
    """``(dx, dy)``, the attribute values (m, as stored: the caller checks them) of our
    lateral x and y spacings of a time-first array of ``ndim`` (2 or 3) dimensions, from
    its attributes and its file's (module docstring); ``dy`` is None for 2-D data, either
    is None where the file does not say.

    Parameters
    ----------
    data_attrs : Mapping[str, Any]
        The array's HDF5 attributes.
    file_attrs : Mapping[str, Any]
        The file's (root group's) HDF5 attributes.
    ndim : int
        The array's dimensions: 2 for ``(n_t, n_x)``, 3 for ``(n_t, n_y, n_x)``.

    Returns
    -------
    dx, dy : Any
        The stored spacing attributes, m (unchecked), or None where missing; ``dy`` is
        None for 2-D data.

    Raises
    ------
    ValueError
        ``ndim`` is neither 2 nor 3.
    """
    if ndim not in (2, 3):
        raise ValueError(f"k-Wave layout data are (t, x) or (t, y, x), got {ndim} dimensions")

    def get(name: str) -> Any:
        return attribute(data_attrs, file_attrs, name)

    if is_kwave_named(data_attrs, file_attrs):
        return (get("dz_m"), get("dy_m")) if ndim == 3 else (get("dy_m"), None)
    return get("dx_m"), get("dy_m") if ndim == 3 else None


def sensor_coordinate_names(kwave_named: bool, ndim: int) -> tuple[str, str | None]:
    """The names of the 1-D datasets that give our lateral x and y sensor coordinates (m), in
    a file of k-Wave's naming or ours: k-Wave's ``sensor_z_m`` (our x) and ``sensor_y_m``
    (our y) in 3-D, ``sensor_y_m`` (our x) in 2-D; ours ``sensor_x_m`` and ``sensor_y_m``.

    Parameters
    ----------
    kwave_named : bool
        Whether the file uses k-Wave's axis names (:func:`is_kwave_named`).
    ndim : int
        The data's dimensions: 2 for ``(n_t, n_x)``, 3 for ``(n_t, n_y, n_x)``.

    Returns
    -------
    x_name, y_name : str, str or None
        The dataset names; ``y_name`` None for 2-D data.

    Raises
    ------
    ValueError
        ``ndim`` is neither 2 nor 3.

    Examples
    --------
    >>> from fpscan.driver.kwave_layout import sensor_coordinate_names
    >>> sensor_coordinate_names(True, 3), sensor_coordinate_names(True, 2), sensor_coordinate_names(False, 3)
    (('sensor_z_m', 'sensor_y_m'), ('sensor_y_m', None), ('sensor_x_m', 'sensor_y_m'))
    """
    if ndim not in (2, 3):
        raise ValueError(f"k-Wave layout data are (t, x) or (t, y, x), got {ndim} dimensions")
    if kwave_named:
        return ("sensor_z_m", "sensor_y_m") if ndim == 3 else ("sensor_y_m", None)
    return ("sensor_x_m", "sensor_y_m") if ndim == 3 else ("sensor_x_m", None)
