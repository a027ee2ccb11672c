"""`fpscan sim`: run the simulated FP scanner on a pseudo-terminal until killed.

The first line on stdout is the device path (e.g. ``/dev/pts/7``) for ``fpscan scan
--device`` or the service; then the simulator runs until SIGINT/SIGTERM, when it writes
the ground-truth record (``--record``) and exits 0.
"""
from __future__ import annotations

import argparse

from fpscan.clients.cli.common import UsageError
from fpscan.constants import C_DEFAULT, C_PLAUSIBLE

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing (`fpscan --help` starts faster)
if TYPE_CHECKING:
    from types import FrameType

    from fpscan.driver.sources import BallSource, ReplaySource, VolumeSource

__all__ = ["COMMAND", "HELP", "add_arguments", "make_source", "run"]

COMMAND = "sim"
HELP = "run the simulated FP scanner on a pseudo-terminal (prints its device path first)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this sub-command's options on ``parser`` (an ``argparse`` sub-parser).
    Frequencies, times and the sound speed take units (``500Hz``, ``2 MHz``, ``5ms``,
    ``1.54 km/s``; bare numbers are SI: ``fpscan.clients.cli.common.quantity``).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser, changed in place.
    """
    from fpscan.clients.cli.common import quantity, seed

    parser.add_argument("--source", nargs="+", default=["balls"], metavar="ARG",
                        help="A-line source: 'balls' (default: built-in phantom of balls and "
                             "a curved tube), 'volume FILE' (HDF5 p0 with dx_m) or "
                             "'replay FILE' (dense k-Wave-layout HDF5, e.g. "
                             "kwave3d_balls_yarn.h5)")
    parser.add_argument("--dataset", default="sensor_data/clean",
                        help="dataset replayed from the replay FILE (default: sensor_data/clean)")
    parser.add_argument("--prf", type=quantity("frequency", "prf"), default=None,
                        help="laser pulse repetition frequency, e.g. 500Hz, for every plan; 0 = unthrottled "
                             "(default: the PRF each plan asks for, its acquisition.prf; 50 Hz for a plan "
                             "that asks for none)")
    parser.add_argument("--faults", default="",
                        help="fault spec, e.g. 'corrupt=1e-4,drop=1e-4,stall=800:2,reset=1200,"
                             "interlock=1500'")
    parser.add_argument("--seed", type=seed, default=0, help="seed of noise and faults")
    parser.add_argument("--record", default=None, metavar="FILE",
                        help="write the ground truth (every A-line sent) to this HDF5 file")
    parser.add_argument("--snr", type=float, default=None, help="peak signal / noise std")
    parser.add_argument("--bandwidth", type=quantity("frequency", "bandwidth"), default=None,
                        help="sensor -3 dB bandwidth, e.g. 20MHz (2nd-order Butterworth)")
    parser.add_argument("--tuning-delay", type=quantity("time", "tuning-delay"), default=0.0,
                        help="bias-wavelength tuning time per point, e.g. 2ms (default 0)")
    parser.add_argument("--laser-tuning-delay", type=quantity("time", "laser-tuning-delay"), default=0.0,
                        help="excitation-laser tuning time when the wavelength changes, e.g. 50ms (default 0)")
    parser.add_argument("--so2", type=float, nargs="+", default=None, metavar="S",
                        help="balls: make the phantom blood-like, HbO2/Hb at this oxygen "
                             "saturation (one value for all balls, or one per ball), so that "
                             "its amplitude follows the excitation wavelength (Prahl's "
                             "extinction table)")
    parser.add_argument("--dc-variation", type=float, default=0.0,
                        help="relative amplitude of the DC-level map (0..1)")
    parser.add_argument("--sensitivity-variation", type=float, default=0.0,
                        help="relative amplitude of the sensitivity map (0..1)")
    parser.add_argument("--byte-rate", type=float, default=None,
                        help="limit the device's output to this many bytes/s")
    parser.add_argument("--sound-speed", type=quantity("speed", "sound speed"), default=C_DEFAULT,
                        help=f"speed of sound of the phantom, e.g. 1.54km/s (balls, volume; default {C_DEFAULT:g} m/s)")
    parser.add_argument("--force", action="store_true",
                        help=f"accept a sound speed outside {C_PLAUSIBLE[0]:g}-{C_PLAUSIBLE[1]:g} m/s (a medium other than tissue/water)")


def make_source(kind_and_file: list[str], *, dataset: str = "sensor_data/clean",
                sound_speed: float = C_DEFAULT,
                so2: list[float] | None = None) -> BallSource | VolumeSource | ReplaySource:
    """The source named on the command line. Raises ValueError for a bad choice.

    Parameters
    ----------
    kind_and_file : list of str
        ``["balls"]``, ``["volume", FILE]`` or ``["replay", FILE]`` (``--source``).
    dataset : str, optional
        The dataset a replay file replays (default ``"sensor_data/clean"``).
    sound_speed : float, optional
        The phantom's sound speed, m/s (balls, volume).
    so2 : list of float, optional
        Oxygen saturation, one for all balls or one per ball (balls only).

    Returns
    -------
    BallSource, VolumeSource or ReplaySource
        The :mod:`fpscan.driver.sources` source.

    Raises
    ------
    UsageError
        An unknown kind, a file given to ``balls`` or missing otherwise, a file that does not
        exist, or ``so2`` without ``balls`` (a ``ValueError``).
    ValueError
        A source that refuses its file or settings.
    """
    from fpscan.driver.sources import BallSource, ReplaySource, VolumeSource, default_phantom

    kind, rest = kind_and_file[0].lower(), kind_and_file[1:]
    if so2 is not None and kind != "balls":
        raise UsageError("--so2 needs --source balls")
    if kind == "balls":
        if rest:
            raise UsageError("--source balls takes no file")
        balls = default_phantom()
        if so2 is not None and len(so2) == 1:
            so2 = so2 * len(balls)
        return BallSource(balls, c=sound_speed, so2=so2)
    if kind in ("volume", "replay"):
        if len(rest) != 1:
            raise UsageError(f"--source {kind} needs exactly one FILE")
        from pathlib import Path

        if not Path(rest[0]).is_file():
            raise UsageError(f"no such file: {rest[0]}")
        if kind == "volume":
            return VolumeSource(Path(rest[0]), c=sound_speed)
        return ReplaySource(Path(rest[0]), dataset=dataset)
    raise UsageError(f"unknown source {kind!r} (balls, volume FILE, replay FILE)")


def run(args: argparse.Namespace) -> int:
    """Run this sub-command with the parsed ``args``; return the exit status.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (:func:`add_arguments`).

    Returns
    -------
    int
        The exit status: 0 on success (refused input and failures raise: :func:`fpscan.clients.cli.main`
        reports them and sets the status).
    """
    import signal
    import sys
    import threading

    from fpscan.driver.faults import FaultSpec
    from fpscan.driver.simulator import SimConfig, SimulatedScanner
    from fpscan.driver.units import check_speeds

    # the speed rule of fpscan plan and recon (a sound speed of 1.5 is km/s typed as m/s; forced, still
    # within 100-10 000 m/s): exit 2
    check_speeds(sound_speed=args.sound_speed, force=args.force)
    if args.record is not None:  # the ground truth is written after each scan, inside the device's loop
        from fpscan.clients.cli.common import check_out_writable

        check_out_writable(args.record, "--record")

    source = make_source(args.source, dataset=args.dataset, sound_speed=args.sound_speed, so2=args.so2)
    config = SimConfig(
        source=source,
        prf=50.0 if args.prf is None else args.prf, prf_from_plan=args.prf is None,
        tuning_delay=args.tuning_delay, laser_tuning_delay=args.laser_tuning_delay,
        dc_variation=args.dc_variation,
        sensitivity_variation=args.sensitivity_variation, bandwidth=args.bandwidth,
        snr=args.snr, byte_rate=args.byte_rate, faults=FaultSpec.parse(args.faults),
        seed=args.seed, record=args.record)
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    sim = SimulatedScanner(config).start()
    try:
        print(sim.path, flush=True)
        rate = "the plan's PRF (50 Hz if it asks for none)" if args.prf is None else f"PRF {args.prf:g} Hz"
        print(f"fpscan sim: {source.describe()}, {rate}, boot id "
              f"{sim.boot_id}; stop with Ctrl-C", file=sys.stderr, flush=True)
        while not stop.wait(0.5):
            pass
    finally:
        sim.stop()
    return 0
