"""Fast FFT lengths: the one rule every transform length the product chooses follows.

A length is *fast* when its largest prime factor is at most 7 (pocketfft, behind
`scipy.fft`, has dedicated passes for the factors 2, 3, 4, 5, 7 of complex transforms and
2, 3, 4, 5 of real ones; any other factor falls back to a generic pass or to Bluestein's
algorithm, several times slower). Pure Python, no imports: choosing a length costs
nothing at start-up.
"""
from __future__ import annotations

__all__ = ["MAX_FACTOR", "largest_prime_factor", "fast_length", "fast_dct1_rows", "fast_lateral", "fast_real_shape", "SQUARE_PAD"]

MAX_FACTOR = 7


def largest_prime_factor(n: int) -> int:
    """Largest prime factor of the integer ``n >= 1`` (1 for n = 1).

    Parameters
    ----------
    n : int >= 1.

    Returns
    -------
    int.

    Raises
    ------
    ValueError for n < 1.

    Examples
    --------
    >>> from fpscan.physics.fast_lengths import largest_prime_factor
    >>> largest_prime_factor(2 * 3 * 7 * 13), largest_prime_factor(1)
    (13, 1)
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n}")
    largest, p = 1, 2
    while p * p <= n:
        while n % p == 0:
            largest, n = p, n // p
        p += 1
    return max(largest, n) if n > 1 else largest


def _smooth(n: int, primes: tuple[int, ...]) -> bool:
    for p in primes:
        while n % p == 0:
            n //= p
    return n == 1


def fast_length(n: int, real: bool = False, even: bool = False) -> int:
    """Smallest fast FFT length >= ``n`` (>= 1): 5-smooth for a real transform (rfft,
    DCT; = ``scipy.fft.next_fast_len(n, real=True)``), 7-smooth for a complex one;
    ``even`` asks for an even length.

    Parameters
    ----------
    n : int >= 1, the shortest acceptable length (samples).
    real : bool
        A real transform (5-smooth) instead of a complex one (7-smooth).
    even : bool
        Only even lengths.

    Returns
    -------
    int >= n.

    Raises
    ------
    ValueError for n < 1.

    Examples
    --------
    >>> from fpscan.physics.fast_lengths import fast_length
    >>> fast_length(97), fast_length(97, real=True)  # 98 = 2·7², 100 = 2²·5²
    (98, 100)
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n}")
    primes = (2, 3, 5) if real else (2, 3, 5, 7)
    m = n
    while not (_smooth(m, primes) and (m % 2 == 0 or not even)):
        m += 1
    return m


def fast_dct1_rows(n: int) -> int:
    """Smallest K >= max(n, 2) whose DCT-I (an FFT of the real, even extension of length
    2 (K - 1)) runs at a fast real length.

    Parameters
    ----------
    n : int, the fewest rows (samples) wanted.

    Returns
    -------
    int K >= max(n, 2).

    Examples
    --------
    >>> from fpscan.physics.fast_lengths import fast_dct1_rows
    >>> fast_dct1_rows(100)  # 2·(101 - 1) = 200 = 2³·5²
    101
    """
    return fast_length(2 * (max(int(n), 2) - 1), real=True, even=True) // 2 + 1


#: the most a common lateral length may pad the shorter axis of a square-pitch grid
SQUARE_PAD = 1.15


def fast_lateral(n_y: int, n_x: int, square: bool = False) -> tuple[int, int]:
    """Lateral transform sizes (n_y', n_x') >= (n_y, n_x) of the planar methods at fast FFT
    lengths: the aperture is zero-padded to them (no data outside the aperture, as the
    continuous formula has it, and less wrap-around than the period of the aperture
    itself); the image is cropped back. x is the rfft axis (factors 2, 3, 5), y a complex
    one (2, 3, 5, 7; :func:`fast_length`); ``n_y`` 1 (a 2-D line scan) stays 1.

    ``square`` (dy = dx): one length for both axes when it pads neither by more than
    :data:`SQUARE_PAD` (15 %), so that k_x and k_y take the same values and columns of equal
    |k_lat| pair up four- to eightfold: the temporal interpolation computes its taps once
    per |k_lat| (226 x 226: 7 300 instead of 14 000 distinct values).

    Parameters
    ----------
    n_y, n_x : int, the grid's lateral sizes (rows along y, columns along x).
    square : bool, whether the pitches are equal (dy = dx).

    Returns
    -------
    tuple of int (n_y', n_x'), each at least the given size.

    Examples
    --------
    >>> from fpscan.physics.fast_lengths import fast_lateral
    >>> fast_lateral(226, 226, square=True)  # 240 = 2⁴·3·5
    (240, 240)
    >>> fast_lateral(100, 130, square=True)  # a common 135 would pad y by 35 %
    (100, 135)
    >>> fast_lateral(1, 1000)  # a line scan
    (1, 1000)
    """
    n_yp = 1 if n_y == 1 else fast_length(n_y)
    n_xp = fast_length(n_x, real=True)
    if square and n_y > 1:
        common = fast_length(max(n_y, n_x), real=True)
        if common <= SQUARE_PAD * min(n_y, n_x):
            return common, common
    return n_yp, n_xp


def fast_real_shape(shape: tuple[int, ...]) -> tuple[int, ...]:
    """Each axis of ``shape`` at the smallest fast length of a real transform (rfft, DCT;
    :func:`fast_length` with ``real=True``); an axis of length 1 stays 1.

    The grid on which a multi-dimensional real transform of an array of ``shape`` runs when
    the array is zero-padded to it (the model-based solver's preconditioner,
    `fpscan.service.recon.tv`).

    Parameters
    ----------
    shape : tuple of int >= 1.

    Returns
    -------
    tuple of int, each at least the given length.

    Raises
    ------
    ValueError for a length < 1.

    Examples
    --------
    >>> from fpscan.physics.fast_lengths import fast_real_shape
    >>> fast_real_shape((1024, 226, 226))  # 226 = 2·113 -> 240 = 2⁴·3·5
    (1024, 240, 240)
    >>> fast_real_shape((97, 1, 64))
    (100, 1, 64)
    """
    return tuple(fast_length(n, real=True) for n in shape)
