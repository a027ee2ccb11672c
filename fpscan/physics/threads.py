"""The compiled kernels' OpenMP threads sleep as soon as a kernel ends.

numba runs the parallel kernels of the reconstruction (`fpscan.physics.nufft_kernels`,
`fpscan.service.recon.kwave`, `fpscan.service.recon.tv`) on OpenMP (libgomp). After each parallel region
a libgomp worker spins, by default for about 8 ms of CPU, before it sleeps. With as many
threads as cores, that worker takes a core from whatever runs next, which is nearly always
an FFT on pocketfft's own threads: on 2 cores, a temporal FFT of a 256 × 128² NER right
after a kernel took 19 ms instead of 13; NER float64 at 256 × 128² went from 1.26-1.29 to
1.03-1.07 of the fast-length FFT, and 2-D NER on the k-Wave tree from 1.72-1.75 to
1.43-1.46, with the passive policy (docs/history/measurements.md, "threads that stop spinning").

Importing this module (`fpscan.physics` does, before any kernel can load libgomp, which
reads its environment once, when loaded) asks for OpenMP's passive wait policy, unless the
user set one: ``OMP_WAIT_POLICY`` in the environment wins. A thread woken for the next
kernel costs microseconds; the kernels run milliseconds.
"""
from __future__ import annotations

import os

__all__ = ["WAIT_POLICY"]

#: OpenMP's wait policy in effect for fpscan's kernels: the user's ``OMP_WAIT_POLICY``, or
#: ``"PASSIVE"``.
WAIT_POLICY = os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
