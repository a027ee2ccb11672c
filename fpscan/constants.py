"""fpscan's physical defaults and limits, each stated once (every layer imports them from here).

Naming: in code the speed of sound is ``c`` (m/s); where a person reads it -- command-line
flags, HTTP fields and every file fpscan writes (plan, scan file, dataset, result volume,
unmixing result) -- it is ``sound_speed`` (``--sound-speed``, ``acquisition.sound_speed``,
the scan file's ``sound_speed`` attribute; ``sound_speed_range``, ``sound_speed_values`` for
the autofocus search). Readers still accept the names older files carry (``c``, the scan
file's ``sound_speed_m_per_s``). k-Wave's own files name it ``c_m_per_s`` and IPASC files
``speed_of_sound``; fpscan reads those names there (and writes IPASC's in its IPASC export).

- :data:`C_DEFAULT`: the speed of sound when the input gives none, 1500 m/s (water near
  20 °C: 1482 m/s; soft tissue 1540 m/s; the value k-Wave's examples use).
- :data:`C_PLAUSIBLE`: speeds accepted without ``force`` (tissue and water), m/s; a value
  outside is most likely a unit mistake (``fpscan.driver.units.check_plausible``).
- :data:`C_LIMITS`: speeds accepted at all (with ``force``: another medium), m/s, lower
  bound exclusive, upper inclusive.
- :data:`C_AUTOFOCUS_RANGE`: the default autofocus search interval, m/s (water at
  10-60 °C and soft tissue); :data:`C_AUTOFOCUS_LIMITS`: the widest interval accepted.
"""
from __future__ import annotations

__all__ = ["C_AUTOFOCUS_LIMITS", "C_AUTOFOCUS_RANGE", "C_DEFAULT", "C_LIMITS", "C_PLAUSIBLE"]

C_DEFAULT: float = 1500.0
C_PLAUSIBLE: tuple[float, float] = (1000.0, 2000.0)
C_LIMITS: tuple[float, float] = (100.0, 10000.0)
C_AUTOFOCUS_RANGE: tuple[float, float] = (1450.0, 1600.0)
C_AUTOFOCUS_LIMITS: tuple[float, float] = (300.0, 6000.0)
